"""From the fitted slip law to the physical quantities of MODEL.md §2.

The fit works with the two combinations the data identify without a mass:
s0 (steady slip of the linear law, 2 m C_rr g / (k n L)) and beta = ds/da
(= 2 m / (1000 k n L) per mm/s^2). Then k/m = 2 / (1000 beta n L) and
C_rr = s0 / (1000 g beta); k needs the mass.
"""

from __future__ import annotations



G = 9.81  # m/s^2
#: the physical range of the slip law: k > 0 (beta > 0) and a rolling resistance (plus
#: drawbar pull over weight) s0 / (1000 g beta) of at least C_RR_MIN. A rubber track on any
#: ground resists rolling by more (steel on rail: ~0.001). Without it a cruise-only
#: recording, which cannot fix beta, let beta wander to 1e4 times any physical value, where
#: it traded with the speed spline's acceleration and shifted s0 by several of its errors
#: (bench_coverage's cruise row: seed 37007 in the posterior, seeds 37014/37026/37027 in
#: the least squares, which crawled along that valley for 300 steps)
C_RR_MIN = 0.001


def beta_max(s0):
    """The largest physical slip slope beta for steady slip s0 (C_rr + F_d/(m g) >= C_RR_MIN)."""
    return s0 / (1000.0 * G * C_RR_MIN)


def reference_slip(n: int, delta_l_mm, L_mm):
    """The reference paper's Eq. 1: s = (n - 1) dl' / L."""
    return (n - 1) * delta_l_mm / L_mm


def delta_l(s_lin, n: int, L_mm):
    """Single horizontal lug deflection dl' = s L / (n - 1) of the elastic (linear) slip, mm."""
    return s_lin * L_mm / (n - 1)


def physical(s0, beta, *, n: int, L: float, mass_kg=None) -> dict:
    """k (N/mm, None without mass), k/m (N/mm/kg), C_rr and dl' (mm) from (s0, beta)."""
    k_over_m = 2.0 / (1000.0 * beta * n * L)
    out = {
        "k_over_m": k_over_m,
        "rolling_resistance": s0 / (1000.0 * G * beta),
        "delta_l_mm": delta_l(s0, n, L),
        "stiffness_N_per_mm": None if mass_kg is None else mass_kg * k_over_m,
    }
    return out


def slip_params_from_physical(k, C_rr, mass_kg, *, n: int, L: float):
    """(s0, beta) of the linear law from k (N/mm), C_rr and the mass (kg)."""
    s0 = 2.0 * mass_kg * C_rr * G / (k * n * L)
    beta = 2.0 * mass_kg / (1000.0 * k * n * L)
    return s0, beta




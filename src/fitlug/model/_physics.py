"""From the fitted slip law to the physical quantities of MODEL.md §2.

The fit works with the two combinations the data identify without a mass:
s0 (steady slip of the linear law, 2 m C_rr g / (k n L)) and beta = ds/da
(= 2 m / (1000 k n L) per mm/s^2). Then k/m = 2 / (1000 beta n L) and
C_rr = s0 / (1000 g beta); k needs the mass.
"""

from __future__ import annotations



G = 9.81  # m/s^2


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




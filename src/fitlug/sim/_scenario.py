"""What a simulated recording is made of: the truth, all in one dataclass."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .._reference import REFERENCE_SLIP as REFERENCE_SLIP


@dataclass
class Scenario:
    """Truth parameters of a simulated recording (mm, s, kg, N).

    Defaults are the reference rig: n = 8, L = 127 mm, 100 fps, 6.5 s, 0.7 m of travel,
    s0 = 0.07716, noise 0.0065 mm (lug) and 0.0041 mm (body), 10 lug and 2 body markers.
    """

    duration_s: float = 6.5
    fps: float = 100.0
    travel_mm: float = 700.0
    rest_s: float = 0.5  # at each end
    ramp_s: float = 1.2
    ramp: str = "cos"  # cos | smoothstep | quintic
    # rig
    n_contact: int = 8
    L_mm: float = 127.0
    lug_pitch_mm: float = 18.36
    n_belt: int = 22  # N: lugs on the belt
    mass_kg: float | None = 10.0
    drawbar_pull_N: float = 0.0  # F_d, known towed load (MODEL.md §2)
    ground: str | None = None  # the rig's [ground] name
    # physics
    slip: float = REFERENCE_SLIP  # s0 of the linear law
    rolling_resistance: float = 0.1
    # geometry
    R_mm: float = 25.0
    e_mm: float = 3.0
    x_off_mm: float = 0.0
    y_off_mm: float = 5.0
    lug_markers: int = 10
    lug_spacing: int = 2  # markers on every second lug
    sigma_start_mm: float = 7.0
    body_markers: tuple = ((-60.0, 75.0), (60.0, 75.0))
    # measurement
    noise_lug_mm: float = 0.0065
    noise_body_mm: float = 0.0041
    write_sigma: bool = False
    effects: dict = field(default_factory=dict)  # id -> {param: value}

    def __post_init__(self):
        # an effect's parameters may be given by their fit.json names (epsilon, phi_rad of
        # wheel_runout): stored under the model's (runout_a, runout_b)
        if isinstance(self.effects, dict):
            from ._effect_names import internal_params

            self.effects = {e: internal_params(e, v) for e, v in self.effects.items()}

    @property
    def pitch(self) -> float:
        return self.lug_pitch_mm

    @property
    def D_mm(self) -> float:
        """Straight-run length so that the belt carries exactly n_belt lugs."""
        return (self.n_belt * self.lug_pitch_mm - 2 * math.pi * self.R_mm) / 2

    @property
    def v_cruise(self) -> float:
        cruise = self.duration_s - 2 * self.rest_s - 2 * self.ramp_s
        return self.travel_mm / (cruise + self.ramp_s)  # each smooth ramp covers v T/2

    @property
    def beta(self) -> float:
        """ds/da from s0, C_rr and F_d: beta = s0 m / (1000 (m C_rr g + F_d))
        (= s0 / (1000 g C_rr) without a drawbar pull)."""
        if not self.drawbar_pull_N:
            return self.slip / (1000.0 * 9.81 * self.rolling_resistance)
        if self.mass_kg is None:
            raise ValueError("a drawbar pull needs the mass (Scenario.mass_kg)")
        return self.slip * self.mass_kg / (1000.0 * self.traction_N)

    @property
    def traction_N(self) -> float | None:
        """Steady traction F0 = m C_rr g + F_d (None without a mass)."""
        if self.mass_kg is None:
            return None
        return self.mass_kg * self.rolling_resistance * 9.81 + self.drawbar_pull_N

    @property
    def stiffness(self) -> float | None:
        if self.mass_kg is None:
            return None
        return 2 * self.traction_N / (self.slip * self.n_contact * self.L_mm)

    def replace(self, **kw) -> "Scenario":
        return dataclasses.replace(self, **kw)

    def check(self) -> None:
        """Raise ValueError("<field>: <problem>") for a scenario that would simulate a
        useless or broken recording (non-finite, out of range, too few frames, a speed
        profile whose rests and ramps do not fit in the duration)."""
        def number(name, lo=None, hi=None, *, lo_open=False, hi_open=False, integer=False):
            value = _finite(getattr(self, name))
            if value is None:
                raise ValueError(f"{name}: must be a finite number, got {getattr(self, name)!r}")
            if integer and not float(value).is_integer():
                raise ValueError(f"{name}: must be an integer, got {value!r}")
            below = lo is not None and (value <= lo if lo_open else value < lo)
            above = hi is not None and (value >= hi if hi_open else value > hi)
            if below or above:
                left = "(" if lo_open else "["
                right = ")" if hi_open else "]"
                raise ValueError(f"{name}: must lie in {left}{lo:g}, "
                                 f"{'inf' if hi is None else f'{hi:g}'}{right}, got {value!r}")
        number("duration_s", 0, lo_open=True)
        number("fps", 0, 1e6, lo_open=True)
        frames = round(self.duration_s * self.fps)
        if not 20 <= frames <= 1_000_000:
            raise ValueError(f"duration_s: {self.duration_s:g} s at {self.fps:g} fps gives "
                             f"{frames} frames; 20 to 1000000 are needed")
        number("rest_s", 0)
        number("ramp_s", 0, lo_open=True)
        if 2 * self.rest_s + 2 * self.ramp_s > self.duration_s + 1e-12:
            raise ValueError(f"duration_s: {self.duration_s:g} s is shorter than the speed "
                             f"profile's two rests and two ramps (2 x {self.rest_s:g} s + "
                             f"2 x {self.ramp_s:g} s)")
        if self.ramp not in ("cos", "smoothstep", "quintic"):
            raise ValueError(f"ramp: must be cos, smoothstep or quintic, got {self.ramp!r}")
        number("travel_mm", 0, lo_open=True)
        number("slip", 0, 1, lo_open=True, hi_open=True)
        number("rolling_resistance", 0, lo_open=True)
        number("n_contact", 2, 1000, integer=True)
        number("L_mm", 0, lo_open=True)
        number("lug_pitch_mm", 0, lo_open=True)
        number("R_mm", 0, lo_open=True)
        number("e_mm", 0)
        number("x_off_mm")
        number("y_off_mm")
        number("n_belt", 3, integer=True)
        if self.D_mm <= 0:
            raise ValueError(f"n_belt: {self.n_belt} lugs of {self.lug_pitch_mm:g} mm do not "
                             f"go round two wheels of radius {self.R_mm:g} mm")
        if self.mass_kg is not None:
            number("mass_kg", 0, lo_open=True)
        number("lug_markers", 1, self.n_belt, integer=True)
        number("lug_spacing", 1, integer=True)
        number("sigma_start_mm")
        if len(self.body_markers) < 1 or not all(
                hasattr(c, "__len__") and len(c) == 2 and all(_finite(v) is not None for v in c)
                for c in self.body_markers):
            raise ValueError(f"body_markers: must be one or more (x, y) offsets in mm, got "
                             f"{self.body_markers!r}")
        number("noise_lug_mm", 0)
        number("noise_body_mm", 0)
        if not isinstance(self.effects, dict):
            raise ValueError(f"effects: must map effect id -> {{param: value}}, got "
                             f"{self.effects!r}")
        from ..model.effects import CATALOG
        for eid, vals in self.effects.items():
            if eid not in CATALOG:
                raise ValueError(f"effects: unknown effect {eid!r}; known: {', '.join(CATALOG)}")
            if not isinstance(vals, dict):
                raise ValueError(f"effects: {eid} must map parameter -> value, got {vals!r}")
            for k, v in vals.items():
                if k not in CATALOG[eid].defaults:
                    from ._effect_names import accepted_names

                    also = accepted_names(eid)
                    raise ValueError(f"effects: {eid} has no parameter {k!r}; known: "
                                     f"{', '.join(CATALOG[eid].defaults)}"
                                     + (f" (or as fit.json names them: {', '.join(also)})"
                                        if also else ""))
                if _finite(v) is None:
                    raise ValueError(f"effects: {eid} {k} must be a finite number, got {v!r}")
        peak = self.peak_friction_ratio()
        if peak is not None and peak >= 1.0:
            raise ValueError(
                f"effects: lug_sliding slide_mu {self.effects['lug_sliding']['slide_mu']:g} "
                f"puts the traction at {peak:.3g} x F_max during the acceleration ramp "
                f"(steady {self.slip * float(self.effects['lug_sliding']['slide_mu']):.3g}); "
                "the track would spin: lower the pull, the mass or the acceleration")

    def peak_friction_ratio(self) -> float | None:
        """max over the recording of F(t)/F_max under lug_sliding (None without it): the
        traction F = m (a/1000 + C_rr g) + F_d peaks in the acceleration ramp; its ratio to
        F_max is slide_mu times the linear law's slip s0 + beta a (MODEL.md §3)."""
        mu = _finite((self.effects.get("lug_sliding") or {}).get("slide_mu", 0.0)) \
            if isinstance(self.effects, dict) else None
        if not mu:
            return None
        from ._profile import speed_profile

        t = np.linspace(0.0, self.duration_s, 4001)
        _, a = speed_profile(t, v_cruise=self.v_cruise, duration=self.duration_s,
                             rest=self.rest_s, ramp=self.ramp_s, shape=self.ramp)
        return float(mu * (self.slip + self.beta * np.max(a)))


def _finite(value) -> float | None:
    """`value` as a finite float (numpy and JAX scalars too), else None (bools: None)."""
    if isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return number if math.isfinite(number) else None

"""What a simulated recording is made of: the truth, all in one dataclass."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

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

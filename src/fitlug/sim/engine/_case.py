"""The settings of one engine case (mm, s, kg, N) and the geometry they imply."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field


@dataclass
class EngineCase:
    """One contact-dynamics run of a planar crawler unit (the engine's truth is measured,
    not set: slip, shear and contact counts come out of the simulation).

    Geometry: a closed chain of `n_links` rigid links of pitch `link_pitch_mm` (hinged at
    their pins) round two wheels whose pin circle has radius `wheel_radius_mm`; one lug on
    every `lug_every`-th link (a rubber belt: short links, lugs every few links). Each lug
    rides its link on a shear slide (spring `k_N_per_mm`, damper `k * tau`) and a normal
    slide (`k_normal_N_per_mm`); its tip is a sphere with Coulomb friction `mu` on the ground.
    """

    name: str = "reference"
    # chain and wheels
    n_links: int = 22
    link_pitch_mm: float = 18.36
    lug_every: int = 1
    wheel_radius_mm: float = 25.0      # pin-circle radius of both wheels
    link_radius_mm: float = 1.5        # the links' capsule radius (pins on its axis)
    link_mass_g: float = 10.0
    bend_Nm_per_rad: float = 0.0       # bending stiffness at each pin (a rubber belt's), 0: free
    wheel_mass_g: float = 50.0
    tension_N: float = 60.0            # the idler's tensioner force (rearward)
    idler_damping: float = 400.0       # N s/m on the tensioner's slide
    mu_wheel: float = 1.2              # wheel on links: the belt is driven by friction
    # lugs
    lug_height_mm: float = 6.0         # pitch line to the tip sphere's centre
    tip_radius_mm: float = 1.0
    lug_mass_g: float = 5.0
    k_N_per_mm: float = 0.25           # shear spring of one lug
    tau_s: float = 0.076               # rubber damping: c = k tau (return time constant)
    k_normal_N_per_mm: float = 20.0    # lug compression
    press_tau_s: float = 0.002         # its damping: c_n = k_normal press_tau
    mu: float = 0.8                    # tip on ground
    # vehicle
    chassis_mass_kg: float = 10.0
    c_rr: float = 0.10                 # rolling resistance: C_rr m g on the chassis
    drawbar_pull_N: float = 0.0
    # motion: rest, accelerate, cruise, decelerate, rest (cos ramps), after `settle_s`
    v_belt_mm_s: float = 150.0         # cruise belt speed the motor aims at
    rest_s: float = 0.3
    ramp_s: float = 1.0
    cruise_s: float = 2.8
    settle_s: float = 0.4
    # numerics
    timestep_s: float = 62.5e-6
    noslip_iterations: int = 0         # MuJoCo's no-slip pass (0: soft friction, may creep)
    # camera and markers
    fps: float = 100.0
    marker_h: float = 0.0              # 0 lug tip .. 1 pitch line (on the link)
    lug_markers: tuple = (0, 1, 2, 3)  # lug indices (consecutive or spread)
    body_markers: tuple = ((-60.0, 45.0), (60.0, 45.0))  # mm from the wheel-centre midpoint
    noise_lug_mm: float = 0.0065
    noise_body_mm: float = 0.0041
    camera_window_mm: tuple | None = None  # ground-frame x the camera sees (None: all)
    notes: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.n_links % self.lug_every:
            raise ValueError(f"{self.name}: n_links {self.n_links} is not a multiple of "
                             f"lug_every {self.lug_every}")
        if not 0.0 <= self.marker_h <= 1.0:
            raise ValueError(f"{self.name}: marker_h {self.marker_h} outside [0, 1]")
        steps = 1.0 / (self.fps * self.timestep_s)
        if abs(steps - round(steps)) > 1e-6:
            raise ValueError(f"{self.name}: the frame interval is not a whole number of steps")
        if self.link_pitch_mm >= 2 * self.wheel_radius_mm:
            raise ValueError(f"{self.name}: links longer than the wheel's diameter")

    @property
    def n_lugs(self) -> int:
        return self.n_links // self.lug_every

    @property
    def lug_pitch_mm(self) -> float:
        return self.link_pitch_mm * self.lug_every

    @property
    def chain_length_mm(self) -> float:
        return self.n_links * self.link_pitch_mm

    @property
    def r_eff_mm(self) -> float:
        """Belt travel per wheel radian of a polygon chain: p / (2 asin(p / 2R))."""
        p = self.link_pitch_mm
        return p / (2 * math.asin(p / (2 * self.wheel_radius_mm)))

    @property
    def wheel_surface_mm(self) -> float:
        """The wheel's radius: a link resting on it has its middle at sqrt(R^2 - (p/2)^2)."""
        r_mid = math.sqrt(self.wheel_radius_mm ** 2 - (self.link_pitch_mm / 2) ** 2)
        return r_mid - self.link_radius_mm

    @property
    def duration_s(self) -> float:
        return 2 * self.rest_s + 2 * self.ramp_s + self.cruise_s

    @property
    def cruise_window_s(self) -> tuple[float, float]:
        """Recording times of the cruise, less 0.1 s at each end."""
        t0 = self.rest_s + self.ramp_s
        return t0 + 0.1, t0 + self.cruise_s - 0.1

    def motor_omega(self, t: float) -> float:
        """The drive wheel's commanded speed (rad/s) at recording time t (s)."""
        w = self.v_belt_mm_s / self.r_eff_mm
        t1, t2 = self.rest_s, self.rest_s + self.ramp_s + self.cruise_s

        def ramp(x):
            x = min(max(x, 0.0), 1.0)
            return 0.5 * (1 - math.cos(math.pi * x))

        return w * (ramp((t - t1) / self.ramp_s) - ramp((t - t2) / self.ramp_s))

    def settings(self) -> dict:
        d = asdict(self)
        d["lug_markers"] = list(self.lug_markers)
        d["body_markers"] = [list(b) for b in self.body_markers]
        if self.camera_window_mm is not None:
            d["camera_window_mm"] = list(self.camera_window_mm)
        d.update(lug_pitch_mm=self.lug_pitch_mm, r_eff_mm=self.r_eff_mm,
                 duration_s=self.duration_s)
        return d

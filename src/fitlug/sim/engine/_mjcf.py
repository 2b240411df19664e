"""The engine's MuJoCo model (MJCF text) of a case: chain, lugs, wheels, skid, chassis.

MuJoCo's x-z plane is our x-y plane (z up). Every joint is a slide along x or z or a hinge
about y, so nothing can leave the plane. Lengths in the XML are metres (SI throughout).
"""

from __future__ import annotations

import math

import numpy as np

from ._case import EngineCase

# collision bits: tips touch the ground only, links touch the wheels and the skid only
_GROUND, _DRIVE = 1, 2


def initial_chain(case: EngineCase) -> dict:
    """A closed polygon of the chain's pins (mm, x-z) to start from, and where the wheels go.

    The chain starts slack: straight runs of `a` links and two half-polygons of `b` links
    on circles a little larger than the wheels' pin circle; the tensioner then pulls the
    idler rearward until the chain wraps both wheels (the settling phase).
    """
    p, R, N = case.link_pitch_mm, case.wheel_radius_mm, case.n_links
    if N % 2:
        raise ValueError(f"{case.name}: n_links must be even")
    b = 1
    while p / (2 * math.sin(math.pi / (2 * b))) < R + 0.4:
        b += 1
    a = (N - 2 * b) // 2
    if a < 2:
        raise ValueError(f"{case.name}: too few links for straight runs")
    r0 = p / (2 * math.sin(math.pi / (2 * b)))
    d0 = a * p
    r_mid = math.sqrt(R * R - p * p / 4)
    z_bot = case.tip_radius_mm + case.lug_height_mm
    pts = [(d0 / 2 - k * p, z_bot) for k in range(a)]
    c = (-d0 / 2, z_bot + r0)
    pts += [(c[0] + r0 * math.cos(-math.pi / 2 - k * math.pi / b),
             c[1] + r0 * math.sin(-math.pi / 2 - k * math.pi / b)) for k in range(b)]
    pts += [(-d0 / 2 + k * p, z_bot + 2 * r0) for k in range(a)]
    c = (d0 / 2, z_bot + r0)
    pts += [(c[0] + r0 * math.cos(math.pi / 2 - k * math.pi / b),
             c[1] + r0 * math.sin(math.pi / 2 - k * math.pi / b)) for k in range(b)]
    pts = np.array(pts)
    d_nom = (case.chain_length_mm - 2 * math.pi * case.r_eff_mm) / 2
    wheel_z = z_bot + r_mid
    return dict(pins=pts, d0=d0, d_nom=d_nom, wheel_z=wheel_z, r_mid=r_mid,
                front_x=d0 / 2, rear_x=-d0 / 2)


def _quat_y(beta: float) -> str:
    return f"{math.cos(beta / 2):.12g} 0 {math.sin(beta / 2):.12g} 0"


def build_mjcf(case: EngineCase) -> tuple[str, dict]:
    """The MJCF text of `case` and the initial geometry (mm) it was built from."""
    g = initial_chain(case)
    m = 1e-3  # mm -> m
    pins = g["pins"]
    nxt = np.roll(pins, -1, axis=0)
    alpha = np.arctan2(nxt[:, 1] - pins[:, 1], nxt[:, 0] - pins[:, 0])
    p, rc = case.link_pitch_mm * m, case.link_radius_mm * m
    k = case.k_N_per_mm * 1e3
    kn = case.k_normal_N_per_mm * 1e3
    H, rt = case.lug_height_mm * m, case.tip_radius_mm * m
    link_cls = (f'contype="{_DRIVE}" conaffinity="0" condim="3" '
                f'friction="{case.mu_wheel} 0.005 0.0001"')

    def lug(i: int) -> str:
        if i % case.lug_every:
            return ""
        j = i // case.lug_every
        return f"""
<body name="lug{j}" pos="{p / 2:.9g} 0 0">
 <joint name="shear{j}" type="slide" axis="1 0 0" stiffness="{k:.9g}" damping="{k * case.tau_s:.9g}" armature="1e-5"/>
 <joint name="press{j}" type="slide" axis="0 0 1" stiffness="{kn:.9g}" damping="{kn * case.press_tau_s:.9g}" armature="1e-5"/>
 <geom name="stem{j}" type="capsule" fromto="0 0 0 0 0 {H:.9g}" size="{rt * 0.8:.9g}" contype="0" conaffinity="0" mass="0"/>
 <geom name="tip{j}" type="sphere" pos="0 0 {H:.9g}" size="{rt:.9g}" mass="{case.lug_mass_g * 1e-3:.9g}" contype="{_GROUND}" conaffinity="0" condim="3" friction="{case.mu} 0.005 0.0001"/>
 <site name="tip{j}" pos="0 0 {H:.9g}"/>
</body>
<site name="base{j}" pos="{p / 2:.9g} 0 0"/>"""

    # the chain: link 0 is free in the plane, each next link hangs on its predecessor's pin
    x0, z0 = pins[0] * m
    chain = (f'<body name="link0" pos="{x0:.9g} 0 {z0:.9g}" quat="{_quat_y(-alpha[0])}">\n'
             '<joint name="cx" type="slide" axis="1 0 0"/><joint name="cz" type="slide" '
             'axis="0 0 1"/><joint name="cr" type="hinge" axis="0 1 0" damping="1e-5"/>\n')
    body_close = ""
    for i in range(case.n_links):
        if i:
            turn = math.remainder(alpha[i] - alpha[i - 1], 2 * math.pi)
            # a belt's bending stiffness: the pin's spring rests where the links are in line
            bend = (f'stiffness="{case.bend_Nm_per_rad:.9g}" springref="{turn:.12g}" '
                    if case.bend_Nm_per_rad else "")
            chain += (f'<body name="link{i}" pos="{p:.9g} 0 0" quat="{_quat_y(-turn)}">\n'
                      f'<joint name="pin{i}" type="hinge" axis="0 1 0" damping="1e-5" '
                      f'{bend}armature="1e-7"/>\n')
        chain += (f'<geom name="link{i}" type="capsule" fromto="0 0 0 {p:.9g} 0 0" '
                  f'size="{rc:.9g}" mass="{case.link_mass_g * 1e-3:.9g}" {link_cls}/>')
        chain += f'<site name="pin{i}" pos="0 0 0"/>' + lug(i) + "\n"
        body_close += "</body>"
    chain += body_close

    rw = case.wheel_surface_mm * m
    wz = g["wheel_z"] * m
    cx = (g["front_x"] - g["d_nom"] / 2) * m  # chassis origin: the nominal wheel midpoint
    half_skid = max(g["d_nom"] / 2 - 0.4 * case.wheel_radius_mm, 5.0) * m
    skid_z = -g["r_mid"] * m + rc + 2e-3  # its underside on the bottom run's links
    wheel_mass = case.wheel_mass_g * 1e-3
    wheel_geom = (f'type="capsule" fromto="0 -0.01 0 0 0.01 0" size="{rw:.9g}" '
                  f'mass="{wheel_mass:.9g}" contype="0" conaffinity="{_DRIVE}" condim="3" '
                  f'friction="{case.mu_wheel} 0.005 0.0001" priority="1"')
    front_local = g["d_nom"] / 2 * m
    rear_local = (g["rear_x"] - g["front_x"] + g["d_nom"] / 2) * m
    Mc = case.chassis_mass_kg
    Iyy = Mc * (0.17 ** 2 + 0.06 ** 2) / 12
    chassis = f"""
<body name="chassis" pos="{cx:.9g} 0 {wz:.9g}">
 <joint name="X" type="slide" axis="1 0 0"/>
 <joint name="Z" type="slide" axis="0 0 1"/>
 <joint name="pitch" type="hinge" axis="0 1 0"/>
 <inertial pos="0 0 0.015" mass="{Mc:.9g}" diaginertia="{Iyy:.9g} {Iyy:.9g} {Iyy:.9g}"/>
 <geom name="skid" type="box" pos="0 0 {skid_z:.9g}" size="{half_skid:.9g} 0.01 0.002" contype="0" conaffinity="{_DRIVE}" condim="1" priority="2" mass="0"/>
 <site name="body" pos="0 0 0"/>
 <body name="front" pos="{front_local:.9g} 0 0">
  <joint name="drive" type="hinge" axis="0 1 0" armature="1e-6"/>
  <geom name="front" {wheel_geom}/>
 </body>
 <body name="idler" pos="{rear_local:.9g} 0 0">
  <joint name="tensioner" type="slide" axis="1 0 0" damping="{case.idler_damping:.9g}" range="-0.05 0.03" limited="true" armature="1e-3"/>
  <inertial pos="0 0 0" mass="0.02" diaginertia="1e-6 1e-6 1e-6"/>
  <body name="rear">
   <joint name="idle" type="hinge" axis="0 1 0" damping="1e-5" armature="1e-6"/>
   <geom name="rear" {wheel_geom}/>
  </body>
 </body>
</body>"""
    ground_friction = f"{case.mu} 0.005 0.0001"
    xml = f"""<mujoco model="fitlug-engine-{case.name}">
<compiler angle="radian" autolimits="true"/>
<option timestep="{case.timestep_s:.9g}" integrator="implicitfast" cone="elliptic" impratio="10" gravity="0 0 -9.81" iterations="60" ls_iterations="20" noslip_iterations="{case.noslip_iterations}"/>
<default><geom solref="0.002 1" solimp="0.95 0.99 0.0005"/></default>
<worldbody>
<geom name="ground" type="plane" size="5 0.5 0.1" contype="0" conaffinity="{_GROUND}" condim="3" friction="{ground_friction}" priority="1"/>
{chassis}
{chain}
</worldbody>
<equality><connect body1="link{case.n_links - 1}" body2="link0" anchor="{p:.9g} 0 0" solref="0.001 1"/></equality>
<actuator><velocity name="motor" joint="drive" kv="20"/></actuator>
</mujoco>"""
    return xml, g

"""Simulated campaigns (MODEL.md §4): recordings of one track at several loads and grounds.

One track (k, n, L, geometry) is driven at chosen drawbar pulls, payloads, speeds and
grounds; each ground has its rolling resistance C_rr and, under the sliding law, its
friction limit F_max. The law is the linear (elastic) one, or Janosi-Hanamoto:

    linear:           s(F) = 2 F / (k n L)
    janosi_hanamoto:  s(F) = -s_K ln(1 - F / F_max),  s_K = 2 F_max / (k n L)

with F = m (a/1000 + C_rr g) + F_d. The sliding law is the catalog's `lug_sliding`
effect with slide_mu = 1 / s_K (the same for every recording of one ground).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..io import write_json
from ..model._physics import G
from ._profile import speed_profile
from ._scenario import Scenario

LAWS = ("linear", "janosi_hanamoto")


@dataclass(frozen=True)
class Run:
    """One recording of a campaign: its load, speed and ground."""

    name: str
    mass_kg: float
    drawbar_pull_N: float = 0.0
    ground: str = "concrete"
    travel_mm: float | None = None  # None: the base scenario's


def law_slip(F, *, k, n, L, F_max=None):
    """Steady slip of the law at traction F (N): linear, or Janosi-Hanamoto with F_max."""
    s_lin = 2.0 * np.asarray(F, float) / (k * n * L)
    if F_max is None:
        return s_lin
    s_K = 2.0 * F_max / (k * n * L)
    return -s_K * np.log1p(-np.asarray(F, float) / F_max)


def law_slope(F, *, k, n, L, F_max=None):
    """ds/dF of the law at traction F (per N)."""
    d = 2.0 / (k * n * L)
    if F_max is None:
        return d * np.ones_like(np.asarray(F, float))
    return d / (1.0 - np.asarray(F, float) / F_max)


def campaign_scenarios(runs, *, k, grounds: dict, law: str = "linear",
                       base: Scenario | None = None) -> list[tuple[Run, Scenario]]:
    """The Scenario of every run. `grounds`: name -> {"C_rr": .., "F_max": .. (sliding)}."""
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}; use one of {', '.join(LAWS)}")
    base = base or Scenario()
    n, L = base.n_contact, base.L_mm
    out = []
    for run in runs:
        gr = grounds[run.ground]
        F0 = run.mass_kg * gr["C_rr"] * G + run.drawbar_pull_N
        kw = dict(mass_kg=run.mass_kg, drawbar_pull_N=float(run.drawbar_pull_N),
                  ground=run.ground, rolling_resistance=gr["C_rr"],
                  slip=2.0 * F0 / (k * n * L), effects=dict(base.effects))
        if run.travel_mm is not None:
            kw["travel_mm"] = run.travel_mm
        if law == "janosi_hanamoto":
            F_max = gr["F_max"]
            if F0 >= F_max:
                raise ValueError(f"run {run.name}: traction {F0:.3g} N >= F_max {F_max:.3g} N")
            kw["effects"]["lug_sliding"] = {"slide_mu": k * n * L / (2.0 * F_max)}
        out.append((run, base.replace(**kw)))
    return out


def campaign_truth(runs, *, k, grounds: dict, law: str, base: Scenario | None = None) -> dict:
    """The truth file of a campaign: the law, k, C_rr and F_max per ground, each run's point."""
    base = base or Scenario()
    n, L = base.n_contact, base.L_mm
    recs = []
    for run in runs:
        gr = grounds[run.ground]
        F0 = run.mass_kg * gr["C_rr"] * G + run.drawbar_pull_N
        F_max = gr.get("F_max") if law == "janosi_hanamoto" else None
        recs.append({"name": run.name, "mass_kg": run.mass_kg,
                     "drawbar_pull_N": run.drawbar_pull_N, "ground": run.ground,
                     "traction_N": F0,
                     "slip": float(law_slip(F0, k=k, n=n, L=L, F_max=F_max))})
    params = {"k_N_per_mm": k}
    if law == "janosi_hanamoto":
        params["F_max_N"] = {g: v["F_max"] for g, v in grounds.items()}
    return {"law": {"id": law, "params": params},
            "stiffness_N_per_mm": k,
            "rolling_resistance": {g: v["C_rr"] for g, v in grounds.items()},
            "F_max_N": ({g: v["F_max"] for g, v in grounds.items()}
                        if law == "janosi_hanamoto" else None),
            "lugs_in_contact": n, "load_bearing_length_mm": L,
            "recordings": recs}


def default_runs(n_runs: int = 8, *, grounds=("concrete", "sand"), pulls=None,
                 masses=(8.0, 10.0)) -> list[Run]:
    """A drawbar-pull campaign: n_runs recordings spread over pulls, masses and grounds."""
    pulls = np.linspace(0.0, 15.0, max(n_runs // len(grounds), 1)) if pulls is None else pulls
    runs = []
    i = 0
    while len(runs) < n_runs:
        g = grounds[i % len(grounds)]
        F_d = float(pulls[(i // len(grounds)) % len(pulls)])
        m = float(masses[i % len(masses)] if len(grounds) == 1 else
                  masses[(i // len(grounds)) % len(masses)])
        runs.append(Run(name=f"r{i + 1:02d}_{g}_{F_d:g}N", mass_kg=m, drawbar_pull_N=F_d,
                        ground=g))
        i += 1
    return runs


def limit_runs(n_runs: int, *, grounds: dict, masses=(8.0, 10.0),
               base: Scenario | None = None, top: float = 0.9,
               peak: float = 0.97, k: float | None = None,
               max_slip: float = 0.5) -> list[Run]:
    """A drawbar-pull campaign that reaches the friction limit (issue 32): on each ground
    the pulls spread the steady traction F0 from no pull up to `top` x F_max, each lowered
    where needed so that the acceleration ramp's traction F0 + m a_max / 1000 stays below
    `peak` x F_max (the track must not spin: Scenario.check refuses that). `grounds`:
    name -> {"C_rr", "F_max"}; `base`: the recordings' scenario (its speed profile). With
    the track's `k`, the top pull is lowered further where the steady slip would pass
    `max_slip` (a stiff track's law at 0.9 F_max slips by 0.9)."""
    base = base or SMALL_BASE
    names = list(grounds)
    per = max(n_runs // len(names), 2)
    runs = []
    for gi, g in enumerate(names):
        gr = grounds[g]
        for j in range(per):
            if len(runs) >= n_runs:
                break
            m = float(masses[j % len(masses)])
            F_roll = m * gr["C_rr"] * G
            sc = base.replace(mass_kg=m, rolling_resistance=gr["C_rr"])
            t = np.linspace(0.0, sc.duration_s, 2001)
            a_max = float(np.max(speed_profile(t, v_cruise=sc.v_cruise, duration=sc.duration_s,
                                               rest=sc.rest_s, ramp=sc.ramp_s,
                                               shape=sc.ramp)[1]))
            F_top = min(top * gr["F_max"], peak * gr["F_max"] - m * a_max / 1000.0)
            if k is not None:
                s_K = 2.0 * gr["F_max"] / (k * base.n_contact * base.L_mm)
                F_top = min(F_top, gr["F_max"] * -np.expm1(-max_slip / s_K))
            F0 = F_roll + (F_top - F_roll) * j / (per - 1)
            F_d = max(F0 - F_roll, 0.0)
            runs.append(Run(name=f"r{len(runs) + 1:02d}_{g}_{F_d:.3g}N", mass_kg=m,
                            drawbar_pull_N=round(F_d, 4), ground=g))
    return runs


#: the issue-32 campaign: a light track (k 0.0524 N/mm) on two grounds whose friction
#: limit a pull of a few newtons reaches (use with `limit_runs`, masses ~1.5 kg)
LIMIT_K = 0.0524
LIMIT_GROUNDS = {"concrete": {"C_rr": 0.06, "F_max": 5.0},
                 "sand": {"C_rr": 0.1, "F_max": 6.0}}

DEFAULT_GROUNDS = {"concrete": {"C_rr": 0.06, "F_max": 50.0},
                   "sand": {"C_rr": 0.15, "F_max": 45.0}}

SMALL_BASE = Scenario(duration_s=3.0, fps=50.0, travel_mm=300.0, rest_s=0.3, ramp_s=0.8,
                      lug_markers=5, lug_spacing=4, body_markers=((-60.0, 75.0),))


def simulate_campaign(out_dir, *, runs=None, k: float = 0.25, grounds: dict | None = None,
                      law: str = "linear", base: Scenario | None = None, seed: int = 0,
                      ) -> dict:
    """Write a simulated campaign into `out_dir`: one folder per run (trajectories.csv,
    rig.toml with mass, drawbar pull and ground, truth.json) and `truth.json` of the law.

    Each run's noise is seeded by seed + its index. Returns the campaign truth.
    """
    from ._simulate import write_simulation

    grounds = dict(DEFAULT_GROUNDS if grounds is None else grounds)
    runs = default_runs() if runs is None else list(runs)
    base = SMALL_BASE if base is None else base
    used = {r.ground for r in runs}
    grounds = {g: v for g, v in grounds.items() if g in used}
    missing = used - set(grounds)
    if missing:
        raise ValueError(f"runs on grounds without C_rr: {sorted(missing)}")
    scen = campaign_scenarios(runs, k=k, grounds=grounds, law=law, base=base)
    os.makedirs(out_dir, exist_ok=True)
    for i, (run, sc) in enumerate(scen):
        write_simulation(os.path.join(out_dir, run.name), sc, seed + i)
    truth = campaign_truth(runs, k=k, grounds=grounds, law=law, base=base)
    truth["seed"] = seed
    write_json(os.path.join(out_dir, "truth.json"), truth)
    return truth


def simulate_points(runs, *, k: float, grounds: dict, law: str = "linear",
                    base: Scenario | None = None, rel_sd_slip: float = 1e-4,
                    rel_sd_slope: float = 1e-3, corr: float = 0.3, seed: int = 0,
                    other_k: dict | None = None) -> list[dict]:
    """Per-recording campaign points drawn from the law without simulating recordings.

    Each point is what one recording's fit gives (see `fitlug.campaign.RecordingPoint`):
    the steady slip and the local slope ds/da at the steady state, with a Gaussian error of
    the stated relative sizes and correlation. Cheap: for statistical checks of the
    campaign model (coverage), not of the per-recording fit. `other_k`: run name -> k of
    another track (a recording that should be flagged).
    """
    base = base or Scenario()
    n, L = base.n_contact, base.L_mm
    rng = np.random.default_rng(seed)
    out = []
    for run in runs:
        gr = grounds[run.ground]
        kk = (other_k or {}).get(run.name, k)
        F0 = run.mass_kg * gr["C_rr"] * G + run.drawbar_pull_N
        F_max = gr.get("F_max") if law == "janosi_hanamoto" else None
        s = float(law_slip(F0, k=kk, n=n, L=L, F_max=F_max))
        b = float(law_slope(F0, k=kk, n=n, L=L, F_max=F_max)) * run.mass_kg / 1000.0
        sd = np.array([rel_sd_slip * s, rel_sd_slope * b])
        cov = np.outer(sd, sd) * np.array([[1.0, corr], [corr, 1.0]])
        y = rng.multivariate_normal([s, b], cov)
        out.append({"name": run.name, "mass_kg": run.mass_kg,
                    "drawbar_pull_N": run.drawbar_pull_N, "ground": run.ground,
                    "slip": float(y[0]), "slope": float(y[1]), "cov": cov.tolist(),
                    "n": n, "L": L})
    return out

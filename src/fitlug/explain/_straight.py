"""The slip read off the straight runs, where the whole-path model does not hold.

A track whose motion comes from contact dynamics (a link chain's polygon, lug tips that
land pre-sheared and spring back at lift-off, a body surging on its lugs: MODEL.md §2
"Real tracks") can leave the base model's fit at chi^2/dof in the thousands. The fit is
then a compromise between parts of the path it does not describe, and its slip is biased
by up to half its value (docs/engine.md: an independent contact-dynamics engine's
recordings). Two parts of the path carry the slip without any of that: the **top run**,
where the belt is unloaded and moves at the belt's speed relative to the body, and the
**body**. Their speeds at cruise give the slip the way the reference study read its
trajectories,

    s = 1 - v_body / v_belt,

with v_body the body's mean speed over the cruise (its markers' measured positions) and
v_belt the mean speed, relative to the body, of the lug markers while they are on the
top run (each visit's straight-line slope). The base fit serves only to find the cruise
(where its belt speed holds a plateau), to tell which lug samples are on the top run
(MARGIN_MM inside its ends, where a chain's links begin to turn onto the wheels) and to
give the body markers' common position.

Its error: the body's speed from a straight line through the cruise with a
Newey-West (autocorrelation-robust) standard error over LAG_S, the belt's speed from
the scatter of the visits' slopes (the small number of visits carried by Student's t),
and, in quadrature, how much the slip changes when the body's speed is taken over the
visits' own time span instead of the whole cruise (a speed that creeps over the cruise,
or a slip still settling after the ramp, makes the two differ; measured on the engine's
recordings 0.000-0.004), and TOP_RUN_REL of the belt's speed: the markers' speed along x
is the belt's only where the top run is straight and steady.

Measured on the engine's ten recordings (docs/engine.md, 2026-11-28): within 3 of its
errors of the engine's slip on 9 (the drive-through misses by 3.2), errors 4-25 % of the
slip, within 0.002 of it on 6, where the whole-path fit was off by up to 50 %.
"""

from __future__ import annotations

import numpy as np

from ..fit._reading import misses_the_data, reads_straight_runs as reads_straight_runs
from ._plateau import SMOOTH_S, plateau
from ._scatter import t_over_z

#: distance kept from each end of the top run (mm): a link turns onto a wheel before its
#: pitch-line point reaches the model's tangent point (a link pitch ~18 mm on the engine)
MARGIN_MM = 20.0
#: a visit of a lug marker to the top run counts from this many samples and seconds
MIN_SAMPLES, MIN_VISIT_S = 8, 0.25
#: the cruise: where the base fit's belt speed stays within PLATEAU of its plateau value
PLATEAU = 0.03
#: the least cruise (s) over which the body is seen for a reading
MIN_CRUISE_S = 1.0
#: Newey-West lag of the body's speed error (s): the body surges at ~1-3 Hz
LAG_S = 1.0
#: the clock's and the top run's slips may differ by this many of their joint errors
AGREE = 4.0
#: where the two agree, the top run's reading stands where the clock's error is more than
#: this many times its own (on the engine's ten recordings 0.1-1.5 times it)
PREFER_TOP = 3.0
#: relative error of the belt's speed read as the top-run markers' speed along x: it is
#: the belt's only where the run is straight and steady, and on the contact-dynamics
#: engine's chains it read 0.3-0.5 % under the chain's travel (six geometries over 7-s
#: cruises, 7-12 of the visits' own errors; docs/engine.md, session 33)
TOP_RUN_REL = 0.005
#: a single visit's belt speed against the cruise's (relative): where nothing else gives a
#: reading (one marked lug: no passage pairs within a turn, one visit of the top run). The
#: visits of the engine's chains scatter by 0.02-0.18 % about their mean (four recordings,
#: 4-12 visits); the top run's straightness (TOP_RUN_REL) comes on top
ONE_VISIT_REL = 0.002


def _hac_slope(t, y, lag_s):
    """Slope of a straight line through (t, y) and its Newey-West standard error."""
    A = np.c_[np.ones_like(t), t - t.mean()]
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    x = A[:, 1]
    g = (x * r)[np.argsort(t, kind="stable")]
    dt = float(np.median(np.diff(np.unique(t)))) if len(np.unique(t)) > 1 else 1.0
    L = max(1, int(lag_s / dt))
    S = float(np.sum(g * g))
    for lag in range(1, min(L, len(g) - 1) + 1):
        S += 2.0 * (1.0 - lag / (L + 1)) * float(np.sum(g[lag:] * g[:-lag]))
    return float(coef[1]), float(np.sqrt(max(S, 0.0)) / np.sum(x * x))


def _cruise(p, lay, nodes):
    """(t1, t2, v_plateau): the longest span where the fit's belt speed (parameters `p`,
    integrated `nodes`) holds a plateau (within PLATEAU of the value it holds longest)."""
    from ..model._host import kinematics_host

    grid = np.asarray(lay.grid)
    tg = np.linspace(float(grid[0]), float(grid[-1]), 2000)
    vt = kinematics_host(p, lay, tg, nodes)["v_t"]
    return plateau(tg, vt, PLATEAU, SMOOTH_S)


def straight_runs_slip(res, margin_mm: float = MARGIN_MM, clock: bool = True,
                       why: list | None = None) -> dict | None:
    """The slip at cruise from the belt's and the body's travel (module docstring).

    The belt's own clock (explain._belt_clock: the lug markers' passages, whole pitches
    and belt lengths, over the body's cruise) where it gives a reading that the top run's
    visits (below) do not contradict (:func:`choose`; with the top run's reading under
    "top_run"); else (or `clock` False) the top run's.

    `res` is a least-squares fit of the base model (its geometry and speed profile are
    used, not its slip). Returns None where the recording does not allow the reading:
    no cruise of MIN_CRUISE_S with the body in view, or fewer than two visits of a lug
    marker to the top run during it. Else a dict: slip, std, v_body_mm_s (and its std),
    v_belt_mm_s (and its std), window_s, visits, window_shift (the slip's change with
    the body's speed over the visits' span), margin_mm, method 'top run' (the clock's
    reading: explain._belt_clock.belt_clock_slip). A list `why` gets the clock's reason
    where it gives no reading.
    """
    import jax.numpy as jnp

    from ..model._host import integrate_host

    from ._belt_clock import belt_clock_slip

    prob = res.problem
    lay = prob.lay
    p = {k: jnp.asarray(v) for k, v in res.params.items()}
    nodes = integrate_host(p, lay)  # once: the cruise, the samples and the body's X read it
    found = None
    if clock:
        try:
            found = belt_clock_slip(res, p, nodes, why)
        except (ValueError, np.linalg.LinAlgError):  # no reading: the top run's stands
            found = None
    top = _top_run_slip(res, margin_mm, p, lay, nodes)
    if found is None and top is None:  # one visit of the top run, where nothing else reads
        top = _top_run_slip(res, margin_mm, p, lay, nodes, min_visits=1)
    return choose(found, top)


def choose(clock: dict | None, top: dict | None) -> dict | None:
    """The clock's reading, unless the top run's disagrees with it by what a miscounted
    belt length makes: more than AGREE of their errors together, and within AGREE of them
    of a whole number of lug pitches over the clock's window travel (a belt length
    miscounted across the time the marked lugs are all on the ground moves the clock's
    slip by a pitch over that travel, ten or more of its errors). Then the top run's, the
    clock's kept beside it for the record. A disagreement that no miscount makes is the top
    run's own: it reads the markers' speed along x, which is the belt's only where the top
    run is straight and steady, and the clock counts the travel along the path (the
    engine's chain, whose unsupported top run moves 4 mm up and down, over a 6-s cruise:
    147.8 mm/s against the clock's 148.4 and the chain's own 148.4; slip 0.0300 +- 0.0004
    and 0.0344 +- 0.0004 for the engine's 0.0346); the clock's reading stands, the top
    run's beside it (`top_run_disagrees`). Where they agree, the top run's too if the
    clock's error is more than PREFER_TOP times its own (the clock's window end read from
    its spline inside a long gap)."""
    if clock is None or top is None:
        return clock or top
    joint = float(np.hypot(clock["std"], top["std"]))
    d = abs(clock["slip"] - top["slip"]) / joint
    if d > AGREE:
        k, off = _pitches_apart(clock, top)
        rec = {"slip": top["slip"], "std": top["std"], "apart_in_errors": d}
        if k is not None and (k == 0 or off > AGREE * joint):
            return {**clock, "top_run_disagrees": {**rec, "pitches_apart": k}}
        return {**top, "belt_clock_rejected": {
            "slip": clock["slip"], "std": clock["std"], "apart_in_errors": d,
            "lugs_on_belt": clock.get("lugs_on_belt")}}
    if clock["std"] > PREFER_TOP * top["std"]:
        # the clock read its window's end inside a long gap (the marked lugs on the
        # ground), from its spline and prior: 30 links of 14 mm, 0.021 against 0.0016
        return {**top, "belt_clock": {"slip": clock["slip"], "std": clock["std"],
                                      "lugs_on_belt": clock.get("lugs_on_belt")}}
    return {**clock, "top_run": {"slip": top["slip"], "std": top["std"]}}


def _pitches_apart(clock: dict, top: dict):
    """(k, rest): the two slips' difference as k whole lug pitches over the clock's window
    travel and what is left of it; (None, None) where the clock's reading does not say its
    travel (then any disagreement is taken for a miscount)."""
    try:
        v_window = clock.get("v_belt_window_mm_s", clock["v_belt_mm_s"])
        travel = v_window * (clock["window_s"][1] - clock["window_s"][0])
        unit = (1.0 - clock["slip"]) * clock["pitch_mm"] / travel
    except (KeyError, TypeError, IndexError):
        return None, None
    if not (np.isfinite(unit) and unit > 0):
        return None, None
    diff = clock["slip"] - top["slip"]
    k = int(np.round(diff / unit))
    return k, abs(diff - k * unit)


def _top_run_slip(res, margin_mm, p, lay, nodes, min_visits: int = 2) -> dict | None:
    """The top run's visits' reading (module docstring); see straight_runs_slip. From
    `min_visits` visits; one visit's belt speed carries ONE_VISIT_REL of it."""
    from ..model._host import kinematics_host, positions_host, sampled_host
    from ..model._model import ctx_of

    prob = res.problem
    cr = _cruise(p, lay, nodes)
    if cr is None:
        return None
    t1, t2, _ = cr
    ctx = ctx_of(p, lay)
    D, R, P = float(ctx.D), float(ctx.R), float(ctx.P)
    obs = {k: np.asarray(v) for k, v in prob.obs.items()}
    sampled = sampled_host(p, lay, nodes)
    u = np.mod(np.asarray(p["sigma0"])[np.asarray(lay.lug_i)] + np.asarray(sampled[1]), P)
    top = (u > D + np.pi * R + margin_mm) & (u < 2.0 * D + np.pi * R - margin_mm)
    bx = np.asarray(positions_host(p, lay, *sampled)[2])
    # the body's position where it is seen: the model's X plus the body markers' mean
    # residual at that frame (the model carries each marker's offset on the body)
    tb = np.asarray(lay.body_t)
    wb = (obs["body_w"] > 0) & np.isfinite(obs["body_x"])
    if not np.any(wb):
        return None
    ut, inv = np.unique(tb[wb], return_inverse=True)
    # each marker's residual less its own median: the body's position does not step
    # where the set of markers in view changes (a drive-through)
    rb = (obs["body_x"] - bx)[wb]
    jb = np.asarray(lay.body_j)[wb]
    for j in np.unique(jb):
        rb[jb == j] -= np.median(rb[jb == j])
    X = (kinematics_host(p, lay, ut, nodes)["X"]
         + np.bincount(inv, rb) / np.bincount(inv))
    in_cruise = (ut >= t1) & (ut <= t2)
    if np.sum(in_cruise) < MIN_SAMPLES or np.ptp(ut[in_cruise]) < MIN_CRUISE_S:
        return None
    v_body, s_body = _hac_slope(ut[in_cruise], X[in_cruise], LAG_S)
    # the top run's lug samples in the cruise at frames where the body is seen
    tl = np.asarray(lay.lug_t)
    li = np.asarray(lay.lug_i)
    dt_frame = float(np.median(np.diff(ut))) if len(ut) > 1 else 1.0
    near = np.abs(ut[np.clip(np.searchsorted(ut, tl), 0, len(ut) - 1)] - tl) < 0.5 * dt_frame
    ok = (top & (obs["lug_w"] > 0) & np.isfinite(obs["lug_x"]) & (tl >= t1) & (tl <= t2)
          & near)
    rel = obs["lug_x"] - np.interp(tl, ut, X)
    slopes, spans = [], []
    for i in np.unique(li[ok]):
        k = np.flatnonzero(ok & (li == i))
        k = k[np.argsort(tl[k], kind="stable")]
        for seg in np.split(k, np.flatnonzero(np.diff(tl[k]) > 3.0 * dt_frame) + 1):
            if len(seg) < MIN_SAMPLES or np.ptp(tl[seg]) < MIN_VISIT_S:
                continue
            slopes.append(np.polyfit(tl[seg], rel[seg], 1)[0])
            spans.append((float(tl[seg][0]), float(tl[seg][-1])))
    n = len(slopes)
    if n < min_visits:
        return None
    w = np.array([b - a for a, b in spans])
    v = np.array(slopes)
    v_belt = float(np.average(v, weights=w))
    if n > 1:
        spread = float(np.sqrt(np.average((v - v_belt) ** 2, weights=w) * n / (n - 1)))
        s_belt = spread / np.sqrt(n) * t_over_z(n - 1)
    else:  # one visit (one marked lug): its speed against the cruise's
        s_belt = ONE_VISIT_REL * abs(v_belt)
    if not (v_belt > 0 and np.isfinite(v_belt)):
        return None
    slip = 1.0 - v_body / v_belt
    # the body's speed over the visits' own span (at least MIN_CRUISE_S, inside the cruise)
    a0, a1 = min(a for a, _ in spans), max(b for _, b in spans)
    if a1 - a0 < MIN_CRUISE_S:
        mid = 0.5 * (a0 + a1)
        a0, a1 = max(t1, mid - 0.5 * MIN_CRUISE_S), min(t2, mid + 0.5 * MIN_CRUISE_S)
    span = (ut >= a0) & (ut <= a1)
    shift = 0.0
    if np.sum(span) >= MIN_SAMPLES and np.ptp(ut[span]) > 0.5 * MIN_CRUISE_S:
        shift = abs((1.0 - _hac_slope(ut[span], X[span], LAG_S)[0] / v_belt) - slip)
    std = float(np.sqrt((s_body / v_belt) ** 2 + (v_body * s_belt / v_belt ** 2) ** 2
                        + shift ** 2 + ((1.0 - slip) * TOP_RUN_REL) ** 2))
    return {"slip": float(slip), "std": std, "v_body_mm_s": float(v_body),
            "v_body_std": float(s_body), "v_belt_mm_s": v_belt, "v_belt_std": float(s_belt),
            "window_s": [t1, t2], "visits": n, "window_shift": float(shift),
            "margin_mm": float(margin_mm), "pitch_mm": P / float(lay.n_belt), "R_mm": R,
            "straightness_rel": TOP_RUN_REL, "method": "top run"}


#: the whole-path model's misfit (rms over the markers' valid samples beyond their noise,
#: mm) beyond which its slip is not read, as a share of the lug pitch: a model that misses
#: the markers by a tenth of a pitch does not say where a lug is (the engine's rubber belt
#: at friction 0.2, its tips at the friction limit in 78 % of contacts, slip 0.59: missed
#: by 14.6 mm rms, its slip read 0.258 +- 0.0006); engine recordings the model bends to
#: are missed by 0.1-0.8 mm
FAR_PITCH = 0.1


def far_from_data(res, why: list | None = None) -> str | None:
    """Why `res`'s slip is not read (its model misses the markers by more than FAR_PITCH
    of a lug pitch, rms beyond their noise), or None; `why`: the straight runs' reasons for
    giving no reading (:func:`straight_runs_slip`), the first of them said after it."""
    from ..model._model import ctx_of

    prob = res.problem
    w = prob.weights
    r = np.asarray(res.residuals)
    if r.shape != w.shape:
        return None
    ok = (w > 0) & np.isfinite(r)
    if not np.any(ok):
        return None
    # beyond the noise: a misfit of chi^2/dof c is sqrt(c - 1) noise levels of systematic
    rms = float(np.sqrt(max(np.mean((r[ok] ** 2 - 1.0) / w[ok] ** 2), 0.0)))
    pitch = (prob.rig.lug_pitch_mm
             or float(ctx_of(res.params, prob.lay).P) / float(prob.lay.n_belt))
    if not rms > FAR_PITCH * pitch:
        return None
    return (f"the model misses the markers by {rms:.1f} mm rms beyond their noise "
            f"({rms / pitch:.0%} of a lug pitch) and the straight runs give no reading"
            + (f": {why[0]}" if why else ""))


def withheld(final, accepted, steps, disc):
    """No claim from a partial reading of a misfit the model does not describe.

    Where the verdict is `unexplained` and the slip had to be read off the straight runs
    (explain._straight: the final model, catalog entries and partial family terms
    included, still misfits at chi^2/dof above GROSS_CHI2), those entries and terms lowered
    chi^2 by taking up a little of a misfit they are not: an image map or marker depth on
    a contact-dynamics engine's recording that has no camera (issue 41). They stay in the
    final model (the headline does not depend on them), but are not named as physics: the
    Explanation lists them in final.robust["withheld"] with the reason, and the families'
    partial terms move to what was tried. The base model's parts (lug_shear: the marker on
    the lug) are not left-out physics and stay. Returns (final, accepted, steps, disc)."""
    import dataclasses

    from ._explanation import BASE_EFFECTS

    far = (final.robust or {}).get("far_from_data")  # its reason, for the record
    if not (reads_straight_runs(final) or misses_the_data(final)):
        return final, accepted, steps, disc
    entries = [e for e in accepted if e not in BASE_EFFECTS]
    # a real track's own physics (the body surging on its lugs: MODEL.md §2) is what the
    # model does not describe, not a reading of that misfit: it is claimed (its term stays)
    real = [t for t in (getattr(disc, "terms", None) or []) if t.choice.extra.get("real_track")]
    terms = [t.to_json() for t in (getattr(disc, "terms", None) or [])
             if not t.choice.extra.get("real_track")]
    if not entries and not terms:
        return final, accepted, steps, disc
    reason = (f"not claimed: the model does not describe the path (chi2/dof "
              f"{final.chi2_per_dof:.0f} with it{'; ' + far if far else ''}), so taking up "
              "part of that misfit is no evidence for it")
    names = entries + [f"{t.get('family')} ({t.get('coordinate')})" for t in terms]
    info = dict(final.robust)
    info["withheld"] = {"readings": names, "reason": reason}
    final = dataclasses.replace(final, robust=info)
    if terms:
        disc = dataclasses.replace(disc, terms=real, tried=list(disc.tried) + [
            {**t, "rejected_because": reason} for t in terms])
    keep = [e for e in accepted if e in BASE_EFFECTS]
    return final, keep, [st for st in steps if st.effect in keep], disc

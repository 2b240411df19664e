"""How much an unexplained misfit can move the estimates through the speed profile.

A cluster-robust (sandwich) covariance holds a misfit that varies like noise from cluster
to cluster. A misfit that does not average out can bias the estimates by more than any
covariance estimated from the residuals shows: a speed modulation at a free frequency
(out of the catalog) leaves a ~20 um wiggle that the base model's adaptive speed spline
cannot follow, and moves s0 by 5-13 least-squares standard errors, the same way in every
recording; its cluster-robust error grows only 1.4-2x (benchmarks/bench_coverage.py,
row speed_mod: 27 % coverage of the 95 % interval).

So, when the verdict is 'unexplained', the model is refitted once with a speed spline
free enough to follow any disturbance of the motion up to ~1 / (4 SPACING_S) Hz
(uniform breakpoints SPACING_S apart, instead of the adaptive layout that must leave
wheel- and lug-locked content in the residuals), from the final fit's values. The
change of each reported quantity between the two fits is a systematic error of the
model's speed profile, added in quadrature to its robust error. Where the disturbance is
a motion, the free fit follows it (chi^2/dof -> 1.0 on speed_mod) and its estimates sit
within ~1 error of the truth, so the shift is the bias; where it is not (a marker
knocked on its lug, an image vibration), the shift is small and the sandwich errors
hold. On clean and explained recordings nothing changes (the refit is not made).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..model import _spline
from ..model._host import speed_values_host

SPACING_S = 0.03  # resolves a motion up to ~8 Hz (4 breakpoints a period)
MAX_COEF = 600  # a longer recording gets wider spacing (cost of the dense refit)


def free_speed_breaks(lay) -> np.ndarray:
    """Uniform breakpoints over the layout's grid, SPACING_S apart (at most MAX_COEF)."""
    grid = np.asarray(lay.grid)
    t0, t1 = float(grid[0]), float(grid[-1])
    n = int(np.ceil((t1 - t0) / SPACING_S))
    n = max(2, min(n, MAX_COEF - _spline.DEGREE))
    return np.linspace(t0, t1, n + 1)


def cannot_hold(res) -> bool:
    """Whether no speed profile can hold `res`'s misfit: the body markers' y does not
    depend on the speed profile (MODEL.md §2: y = c_yj, no catalog effect moving the body
    or the image in the model), so its weighted scatter about each marker's mean is a
    floor under any refit's chi^2; above twice the dof the refit cannot pass (a body that
    pitches and heaves on its lugs: the engine's recordings, 10^4-10^5 of floor)."""
    from ..model.effects import CATALOG

    lay = res.problem.lay
    if any(getattr(CATALOG[e], "body_dy", None) is not None
           or getattr(CATALOG[e], "image", None) is not None for e in lay.effects):
        return False
    obs = res.problem.obs
    w = np.asarray(obs["body_w"], float)
    y = np.asarray(obs["body_y"], float)
    j = np.asarray(lay.body_j)
    ok = (w > 0) & np.isfinite(y)
    if not np.any(ok):
        return False
    w2, y, j = w[ok] ** 2, y[ok], j[ok]
    mean = np.bincount(j, w2 * y) / np.maximum(np.bincount(j, w2), 1e-300)
    floor = float(np.sum(w2 * (y - mean[j]) ** 2))
    return floor > 2.0 * max(res.dof, 1)


def speed_sensitivity(res) -> dict | None:
    """Refit `res` with a free speed profile; {quantity: shift} and how the refit went.

    Returns None when the refit fails (the robust errors then stand alone).
    """
    from ..fit import fit_problem

    prob = res.problem
    lay = prob.lay
    br = free_speed_breaks(lay)
    if len(br) - 1 + _spline.DEGREE <= lay.n_coef:  # not freer than the base layout
        return None
    # the base speed profile, projected on the free basis: the refit starts at the base fit
    speed = np.asarray(speed_values_host(lay, jnp.asarray(res.params["v"], float))[0])
    p = {k: np.asarray(v, float) for k, v in res.params.items()}
    p["v"] = _spline.fit_banded(np.asarray(lay.grid), speed, br)
    prob2 = dataclasses.replace(prob, lay=lay.with_breaks(br))
    try:
        with np.errstate(all="ignore"):  # its covariance only sizes the shift's own scatter
            res2 = fit_problem(prob2, p, free=list(res.packing.names), max_steps=100,
                           params=getattr(res, "constraints", None),
                               require_convergence=False)
    except Exception:  # noqa: BLE001 - a failed sensitivity refit leaves the errors as they are
        return None
    if not np.isfinite(res2.chi2) or res2.chi2 > res.chi2 * (1 + 1e-6):
        return None
    shift, raw = {}, {}
    for q, a in res.quantities.items():
        b = res2.quantities.get(q)
        if b is None or a.value is None or b.value is None:
            continue
        d = float(b.value) - float(a.value)
        if not np.isfinite(d):
            continue
        raw[q] = abs(d)
        # the shift between two fits of one data set has its own scatter: without any
        # bias E[d^2] = V_free - V_base (the free fit is the less efficient one; Hausman).
        # Only the excess is a bias: adding d^2 whole made the errors of k and C_rr under
        # an image vibration 8x too wide (bench_coverage: rms z 0.12)
        v_noise = ((b.std or 0.0) ** 2 - (a.std or 0.0) ** 2
                   if b.std is not None and a.std is not None
                   and np.isfinite(b.std) and np.isfinite(a.std) else 0.0)
        shift[q] = float(np.sqrt(max(d * d - max(v_noise, 0.0), 0.0)))
    return {"spacing_s": float(br[1] - br[0]), "n_coef": int(prob2.lay.n_coef),
            "n_coef_base": int(lay.n_coef), "chi2_per_dof": float(res2.chi2_per_dof),
            "chi2_per_dof_base": float(res.chi2_per_dof), "shift": shift, "shift_raw": raw,
            "converged": bool(res2.converged), "_fit": res2}


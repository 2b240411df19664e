"""Tracker systematics: a structured misfit a tracker cannot avoid is not physics.

A tracker's position error is not all white: a marker's centroid carries a small bias that
depends on how the marker is seen (its patch, the lighting, the pixel grid: constant over
a path segment, where the marker's orientation and place in the image change little) and
on motion blur (so on its speed). A tracked recording of a clean, rendered video shows it
as ~0.005 px (2 um) per marker and segment, enough for the detection tests to fire on
thousands of samples.

When the explanation would end 'unexplained', this module asks whether the remaining
misfit is of that kind and size:

1. the nuisance model: one offset per (marker, path segment, axis) cell and one term
   proportional to the body speed per cell (blur), fitted together with every parameter
   of the final model (one linear least-squares step with its exact Jacobian);
2. it must hold the misfit: its residuals pass detection (fitlug.explain.detect), i.e. no
   structure is left that per-marker-per-segment offsets cannot carry (a 3.3 Hz image
   vibration, a marker that shifts at some time, stays);
3. its amplitude must sit below the tracker-systematics floor: the RMS over the samples
   of what fitting it changes in the residuals, in um, at most FLOOR_PX (0.01 px, twice the bias measured
   on the project's renders) times the recording's mm per pixel (from its x_px column),
   else FLOOR_UM (3 um: 0.01 px at the reference camera's 0.39 mm/px, rounded up);
4. its effect on the slip must be negligible: the slip moves by less than SLIP_EFFECT_MAX
   (1) standard error when the nuisance is added, or by no more than freeing that many
   parameters moves it through the noise alone: |delta| <= SLIP_SHIFT_Z (2.5) times
   sqrt(V1 - V0), V1 and V0 the slip's variance with and without the nuisance (a Hausman
   test: without any systematic, delta ~ N(0, V1 - V0)), and never by more than
   SLIP_EFFECT_CAP (3) standard errors. Measured on a short rendered and tracked clean
   clip (no physics in it): the ~90 nuisance columns doubled the slip's variance and moved
   it by 1.96 standard errors (1.98 sqrt(V1 - V0)), away from the truth (z -0.7 -> -2.7):
   the noise of freed parameters, not an effect of the tracker's bias, which the old rule
   (1 standard error) called 'unexplained'.

The nuisance is then carried in the errors: every reported quantity takes the larger of
its least-squares error and its error with the nuisance fitted beside the model
(explain._robust.nuisance_result; the posterior follows). Per-segment offsets of a few
um trade with the geometry and the slip law: on benchmarks/bench_coverage.py's
systematics row the slip of a recording called 'none' lay 2.7 least-squares errors from
the truth, 1.15 errors with the nuisance carried (errors x 2.3).

Then the verdict follows the named effects ('none' without any) and fit.json's
`discrepancy.systematics` reports {amplitude_um, share_of_misfit, slip_effect, note}.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..fit._result import derived
from ._detect import detect
from ..fit._rowchunks import RowChunks
from ._engine import jacobian_of
from ._normal import pinv_factor
from ._locate import locate
from ._table import structured_misfit

FLOOR_PX = 0.01
FLOOR_UM = 3.0
SLIP_EFFECT_MAX = 1.0
SLIP_SHIFT_Z = 2.5  # two-sided 1.25 %: the level of each of detect's four tests (5 % / 4)
SLIP_EFFECT_CAP = 3.0
MIN_CELL = 10


def floor_um(rec) -> tuple[float, str]:
    """(floor in um, how it was set) for a recording."""
    if rec.x_px is not None:
        ok = np.isfinite(rec.x_px) & np.isfinite(rec.x)
        if ok.sum() > 10 and np.ptp(rec.x_px[ok]) > 0:
            mm_per_px = float(abs(np.polyfit(rec.x_px[ok], rec.x[ok], 1)[0]))
            if np.isfinite(mm_per_px) and mm_per_px > 0:
                return (1000.0 * FLOOR_PX * mm_per_px,
                        f"{FLOOR_PX:g} px at {mm_per_px:.4g} mm/px (from the x_px column)")
    return FLOOR_UM, f"{FLOOR_UM:g} um default ({FLOOR_PX:g} px at ~0.3-0.4 mm/px)"


def _design(geo):
    """Nuisance columns (S, q) in weighted-residual units per mm, and their cell labels."""
    (off, spd, v_off, v_spd), labels = _design_sparse(geo)
    S, q = len(geo.t), len(labels)
    N = np.zeros((S, q))
    rows = np.arange(S)
    N[rows[off >= 0], off[off >= 0]] = v_off[off >= 0]
    N[rows[spd >= 0], spd[spd >= 0]] = v_spd[spd >= 0]
    return N, labels


def _design_sparse(geo):
    """:func:`_design` as at most two entries per sample (a sample lies in one cell): the
    column of its cell's offset and of its speed term (-1 for none) and their values;
    and the columns' cell labels."""
    vn = np.abs(geo.v) / max(float(np.max(np.abs(geo.v))), 1e-12)
    S = len(geo.t)
    off, spd = np.full(S, -1), np.full(S, -1)
    labels = []
    key = (geo.marker * 5 + geo.segment) * 2 + geo.axis
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    ends = np.r_[starts[1:], len(ks)]
    for a, b in zip(starts, ends):
        idx = order[a:b]
        idx = idx[geo.valid[idx]]
        if len(idx) == 0 or len(idx) < MIN_CELL:
            continue
        k = int(key[idx[0]])
        off[idx] = len(labels)
        labels.append(k)
        if np.ptp(vn[idx]) > 0.2:  # a speed term only where the speed changes
            spd[idx] = len(labels)
            labels.append(k)
    w = np.where(geo.valid, geo.weight, 0.0)
    return (off, spd, w, w * vn), np.array(labels, int)


def _nuisance_fit(res, geo, r):
    """Least squares of the residuals r on [J, N] (the fit's Jacobian and the nuisance
    design), columns scaled to unit norm, minimum-norm solution: (delta, r2 = r + A delta,
    number of model columns, number of nuisance columns, the model's covariance with the
    nuisance carried, J^T J). Dense on short recordings; on
    long ones from the normal equations, J^T J and J^T N accumulated over time chunks
    and N (two entries per sample) never formed."""
    prob = res.problem
    fixed = {k: jnp.asarray(v, float) for k, v in res.params.items()
             if k not in res.packing.names}
    J = jacobian_of(res.flat, fixed, res.packing, prob.lay, prob.obs)
    if not isinstance(J, RowChunks):
        N, _ = _design(geo)
        A = np.hstack([J, N])
        d = np.sqrt(np.sum(A * A, 0))
        d = np.where(d > 0, d, 1.0)
        sol, *_ = np.linalg.lstsq(A / d, -r, rcond=1e-10)
        delta = sol / d
        As = A / d
        n_p = J.shape[1]
        cov = (np.linalg.pinv(As.T @ As, rcond=1e-12, hermitian=True)
               / np.outer(d, d))[:n_p, :n_p]
        return delta, r + A @ delta, n_p, N.shape[1], cov, J.T @ J
    (off, spd, v_off, v_spd), labels = _design_sparse(geo)
    q, n_p = len(labels), J.n_par
    JJ, g = J.normal(r)  # J^T J, J^T r
    JN = np.zeros((n_p, q))
    for rows, Jc in J:
        for col, val in ((off, v_off), (spd, v_spd)):
            c = col[rows]
            use = np.flatnonzero(c >= 0)
            if len(use) == 0:
                continue
            order = use[np.argsort(c[use], kind="stable")]
            cs = c[order]
            starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
            JN[:, cs[starts]] += np.add.reduceat(Jc[order] * val[rows][order, None], starts,
                                                 0).T
    NN = np.zeros((q, q))
    Nr = np.zeros(q)
    for col, val in ((off, v_off), (spd, v_spd)):
        use = col >= 0
        NN[np.diag_indices(q)] += np.bincount(col[use], val[use] ** 2, q)
        Nr += np.bincount(col[use], val[use] * r[use], q)
    both = (off >= 0) & (spd >= 0)
    cross = np.zeros((q, q))
    np.add.at(cross, (off[both], spd[both]), v_off[both] * v_spd[both])
    NN += cross + cross.T
    A = np.block([[JJ, JN], [JN.T, NN]])
    b = np.r_[g, Nr]
    M = pinv_factor(A, 1e-14)
    delta = -(M @ (M.T @ b))
    dn = np.r_[delta[n_p:], 0.0]  # column -1 (no entry) takes 0
    r2 = r + J.matvec(delta[:n_p]) + v_off * dn[off] + v_spd * dn[spd]
    cov = (M @ M.T)[:n_p, :n_p]  # the pseudo-inverse of the normal matrix, model block
    return delta, r2, n_p, q, cov, JJ


def _quad_pinv(JJ: np.ndarray, g: np.ndarray, rcond: float = 1e-12) -> float:
    """g^T (J^T J)^+ g with the eigenvalue cut of the least-squares covariance (columns
    scaled to unit norm first, as the fit's covariance is)."""
    d = np.sqrt(np.clip(np.diag(JJ), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    w, V = np.linalg.eigh(JJ / np.outer(d, d))
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    u = V.T @ (g / d)
    return float(np.sum(inv * u * u))


def tracker_systematics(res, geo, alpha: float) -> dict | None:
    """The `systematics` block when the misfit of fit `res` is tracker-like and below the
    floor with a negligible effect on the slip; else None (with the reason in `why`)."""
    prob = res.problem
    r = np.where(geo.valid, np.asarray(res.residuals, float), 0.0)
    delta, r2, n_p, n_nuis, cov_model, JJ = _nuisance_fit(res, geo, r)
    # slip: moved by the nuisance, against its least-squares error
    fixed_np = {k: jnp.asarray(v, float) for k, v in res.params.items()
                if k not in res.packing.names}

    def slip_of(fl):
        return derived(res.packing.unpack(fl, fixed_np), prob.lay, prob.rig.mass_kg)["slip"]

    g = np.asarray(jax.jit(jax.grad(slip_of))(jnp.asarray(res.flat)))  # one program
    d_slip = float(g @ delta[:n_p])
    s_std = float(res.slip.std or 0.0)
    effect = abs(d_slip) / s_std if s_std > 0 else np.inf
    # the shift's spread from the noise alone: sqrt(V1 - V0), the slip's variance with and
    # without the nuisance (unit weights: the residuals are in noise units)
    v1 = float(g @ cov_model @ g)
    v0 = _quad_pinv(JJ, g)
    null_std = float(np.sqrt(max(v1 - v0, 0.0)))
    shift_z = abs(d_slip) / null_std if null_std > 0 else np.inf
    # amplitude of the systematic: what fitting the nuisance (and refitting the model with
    # it) changes in the residuals, um RMS; offsets that the model's own parameters can
    # take (a body marker's offset) cancel here instead of counting twice
    w = np.where(geo.valid, geo.weight, 1.0)
    sys_mm = np.where(geo.valid, (r2 - r) / w, 0.0)
    amp = 1000.0 * float(np.sqrt(np.sum(sys_mm ** 2) / max(geo.n, 1)))
    floor, how = floor_um(prob.rec)
    M, _ = structured_misfit(geo, r)
    M2, _ = structured_misfit(geo, r2)
    share = float(np.clip((M - M2) / M, 0.0, 1.0)) if M > 0 else 0.0
    det = detect(geo, r2, res.dof - n_nuis, sigma_estimated=True, alpha=alpha)
    holds = det.consistent or not locate(geo, r2, det).parts
    block = {"amplitude_um": amp, "floor_um": floor, "share_of_misfit": share,
             "slip_effect": {"delta": d_slip, "std": s_std, "in_std": effect,
                             "noise_std": null_std, "z": shift_z},
             "n_nuisance": int(n_nuis),
             "note": (f"per-marker-per-segment offsets and speed terms (the tracker's bias "
                      f"and blur) carry {100 * share:.0f} % of the structured misfit with "
                      f"{amp:.2g} um RMS, below the tracker-systematics floor of "
                      f"{floor:.2g} um ({how}); the slip moves by {effect:.2f} standard "
                      f"errors when they are fitted ({shift_z:.2f} times its spread from the "
                      "noise of the freed nuisance): a measurement floor, not physics")}
    why = None
    if not holds:
        why = "a structure that per-marker-per-segment offsets do not carry remains"
    elif amp > floor:
        why = f"amplitude {amp:.3g} um above the floor {floor:.3g} um"
    elif effect > SLIP_EFFECT_MAX and (shift_z > SLIP_SHIFT_Z or effect > SLIP_EFFECT_CAP):
        why = (f"moves the slip by {effect:.2f} standard errors ({shift_z:.2f} times the "
               f"{null_std:.2g} that freeing the nuisance moves it through the noise alone)")
    block["why_not"] = why
    block["_cov"] = cov_model  # not for fit.json (see Explanation.to_json)
    return block

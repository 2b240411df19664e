"""Glitches: isolated gross errors of the tracker, found, listed and kept out of the fit.

A tracker now and then jumps for one frame or two to a reflection or a neighbour
(MODEL.md §2, end): a sample a fraction of a millimetre or more off, while the samples
around it are fine. Such a sample is not physics: it is found here, its weight set to
zero, and it is listed (fit.json `glitches`).

The rule (a test on standardised residuals with the noise known from the data):

1. Residuals of the fit, data minus model, in units of the noise sigma per role (which
   comes from 4th differences of the data, median/MAD based and clipped, so a few
   glitches do not move it), for every valid sample, flagged ones included.
2. For each sample t of a marker, the *local level* of its residuals: a quadratic in time
   (a line when fewer neighbours) fitted, per axis, to its neighbours 2 to 5 frames away
   on both sides (t-1 and t+1 are left out, so that a glitch of two consecutive frames
   does not pull its own prediction). The model's slow misfit (an effect not yet in the
   model, a speed profile pulled by the glitch itself) is smooth over those 11 frames
   and the local level follows it.
3. The statistic z_t^2 = (e_x^2 + e_y^2) / ((1 + h_t) s_t^2), with e the sample's
   deviation from its local level, h_t the prediction's leverage (the variance of the
   prediction in units of sigma^2) and s_t^2 = max(1, chi^2/dof of the neighbours about
   their fit): a sample is judged against the local roughness when that is larger than
   the noise. Under the noise alone z^2 is chi^2 with 2 degrees of freedom (a little
   less extreme: the clip at 1). The fit leaves out one neighbour that is itself far off
   the others (another glitch nearby). z is then capped by the sample's distance from the
   mean of each side's neighbours alone: a glitch stands off both sides, the edge of a
   step agrees with one of them.
4. Threshold: the family-wise false-alarm rate ALPHA = 1 % over all N valid samples
   (Bonferroni): P(z^2 > c^2) = exp(-c^2/2) = ALPHA / N, c = sqrt(2 ln(N / ALPHA)).
   N = 7800 gives c = 5.2 sigma (34 um for a 6.5 um lug noise).
5. Samples above c are flagged worst first (a local maximum within 5 frames), the
   neighbour fits recomputed without them, until none is left above c. A run of more than
   MAX_RUN consecutive flagged frames is not isolated and is unflagged, and so are flags
   that COMMON (3) or more markers share within a frame: glitches are independent, and a
   common jump (a lost frame, an image shake) is physics or timing for the explanation.
   A flag in such a frame stays a glitch where its deviation stands further than ON_TOP
   times the largest of the others' from their common (median) one: a lost frame moves
   each marker by its own speed, a shake all alike, a misfit's structure by the model's
   error there; a jump to a reflection in the same frame adds millimetres of its own.
6. Isolation is what tells a glitch from a marker that jumps and STAYS jumped: after such a
   step every sample agrees with its neighbours, and the few samples at the step see
   neighbours that disagree among themselves (s_t is large), so nothing is flagged and the
   step remains a located mismatch of that marker.

:func:`fitlug.fit.fit` sets the flagged samples' weights to zero, refits, and repeats the
search on the new residuals (flags are recomputed from scratch each round, so a flag
caused by the first fit's distortion is dropped) until the set no longer changes (at most
SETTLED_FLIPS samples, or 2 % of the set, flip across the threshold), at most MAX_ROUNDS
rounds, and one where the refit still misfits grossly (GROSS_ROUNDS_CHI2). The problem
keeps the zero weights, so the explanation's candidate fits and the posterior see the
clean problem.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _exported, _jaxconfig  # noqa: F401
from ..model import predict, predict_from_nodes

ALPHA = 0.01
MAX_RUN = 3
MAX_ROUNDS = 3
#: a set whose refit flips at most this many samples (or 2 % of it) is stable
SETTLED_FLIPS = 2
#: after its first refit, a fit still misfitting at chi^2/dof above this (the explanation's
#: GROSS_CHI2) ends the rounds: the rule's flags there are mostly the misfit's structure,
#: a different set each round (mu012, a contact-dynamics engine's recording at chi^2/dof
#: 2 900: rounds of 139, 214 and 282 steps, 10 s), and a glitch, isolated, is found the
#: same by the first search (its test is local: a sample against its neighbours)
GROSS_ROUNDS_CHI2 = 25.0
NEAR, FAR = 2, 5  # neighbours used: frames NEAR..FAR away on each side
_MAX_PASSES = 20
COMMON = 3  # markers flagged in one frame: a common cause, not glitches
#: ... unless a flag's deviation stands further off the others' median deviation than
#: this many times the largest of theirs (a lost frame: a top-run lug moves twice as far
#: as the body, at most; engine-recording glitches of 3-6 mm on a common 1.8 mm: 2.7-3.0)
ON_TOP = 2.5
NEIGHBOUR_OUT = 5.0  # sigma: a neighbour this far off the others' fit is left out

RULE = ("standardised residual of each sample (noise per role from 4th differences of the "
        "data) against the local level of its marker's residuals (a quadratic through the "
        f"neighbours {NEAR}-{FAR} frames away on both sides), scaled by the prediction's "
        "leverage and the neighbours' own roughness; flagged when z^2 > 2 ln(N / alpha), a "
        f"family-wise false-alarm rate alpha = {ALPHA:g} over the N valid samples "
        f"(Bonferroni, chi^2 with 2 dof); runs of more than {MAX_RUN} consecutive frames "
        f"are not isolated and not glitches, nor are flags that {COMMON} or more markers "
        "share within a frame (a common cause) unless one stands off the others' median "
        f"deviation by more than {ON_TOP:g} times the largest of theirs; flagged samples get "
        "zero weight and the fit is repeated until the set is stable "
        f"(at most {MAX_ROUNDS} rounds; one where the refit "
        f"still misfits at chi^2/dof above {GROSS_ROUNDS_CHI2:g})")


def threshold(n_samples: int, alpha: float = ALPHA) -> float:
    """c with P(chi^2_2 > c^2) = alpha / n_samples (Bonferroni over the samples)."""
    return math.sqrt(2.0 * math.log(max(n_samples, 1) / alpha))


@jax.jit
def _predict(p, lay):
    return tuple(predict(p, lay))


@jax.jit
def _integrate(p, lay):
    from ..model import integrate

    return integrate(p, lay)


_predict_from_nodes = jax.jit(predict_from_nodes)


def _positions(p: dict, lay, obs) -> tuple:
    """The model's (lug_x, lug_y, body_x, body_y) at every sample (numpy); on a long
    recording one time block's model evaluation at a time (:func:`fitlug.fit._chunks.
    time_blocks`: the model's per-sample temporaries of one block, the node values
    integrated once; the same values)."""
    from ._chunks import time_blocks

    blocks = time_blocks(lay, obs, plans=False)
    if blocks is None:  # on bucketed shapes (_buckets), cut back
        from ._buckets import pad_model

        pm = pad_model(p, lay)
        S_l, S_b = lay.lug_t.shape[0], lay.body_t.shape[0]
        # through a module kept on disk (fitlug._exported): a new process skips its tracing
        pos = _exported.call("glitch_predict", _predict, (), *(pm or (p, lay)))
        return tuple(np.asarray(a)[:n] for a, n in zip(pos, (S_l, S_l, S_b, S_b)))
    S_l, S_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    out = (np.zeros(S_l), np.zeros(S_l), np.zeros(S_b), np.zeros(S_b))
    nodes = _integrate(p, lay)
    for lay_k, rows_k in zip(blocks.lays, blocks.rows):
        lx, ly, bx, by = (np.asarray(a) for a in _predict_from_nodes(p, lay_k, nodes))
        nl, nb = len(lx), len(bx)
        real_l, real_b = rows_k[:nl] >= 0, rows_k[2 * nl:2 * nl + nb] >= 0
        il = rows_k[:nl][real_l]  # lug x rows are the lug sample indices
        ib = rows_k[2 * nl:2 * nl + nb][real_b] - 2 * S_l  # body x rows: 2 S_l + index
        out[0][il], out[1][il] = lx[real_l], ly[real_l]
        out[2][ib], out[3][ib] = bx[real_b], by[real_b]
    return out


def standardised_residuals(res) -> dict:
    """Data minus model in units of the role's noise, for every valid sample (flagged too).

    Returns {'lug': (ex, ey, valid), 'body': (...)} over the problem's lug / body rows.
    """
    prob = res.problem
    p = {k: jnp.asarray(v, float) for k, v in res.params.items()}
    lx, ly, bx, by = _positions(p, prob.lay, prob.obs)
    rec = prob.rec
    out = {}
    for role, rows, mx, my in (("lug", prob.lug_rows, lx, ly), ("body", prob.body_rows, bx, by)):
        x, y = np.asarray(rec.x[rows], float), np.asarray(rec.y[rows], float)
        valid = np.isfinite(x) & np.isfinite(y)
        s = float(prob.noise[role])
        ex = np.where(valid, (np.where(valid, x, 0.0) - mx) / s, 0.0)
        ey = np.where(valid, (np.where(valid, y, 0.0) - my) / s, 0.0)
        out[role] = (ex, ey, valid)
    return out


def _fit_local(w, u, q, E, zi):
    """Weighted local fits, per axis, of the residual series E on each sample's neighbours.

    w (n, K) neighbour weights (0/1), u (K,) the neighbours' offsets in units of FAR, q (n,)
    1.0 where the fit is a quadratic in u, 0.0 where a line, zi (n, K) neighbour positions.
    The 3x3 normal matrices come from the weighted power sums of u and are inverted in
    closed form (cofactors), every sample at once. Returns (coefficients per axis (n, 3),
    the leverage of the prediction at u = 0 in units of sigma^2, RSS over both axes).
    """
    u2 = u * u
    one = np.ones_like(u)  # sums over the K neighbours as products (numpy's sum over a
    s0, s1, s2 = w @ one, w @ u, w @ u2  # short last axis is ~30x slower)
    s3, s4 = w @ (u * u2), w @ (u2 * u2)
    # A = sum_k w_k V_k V_k^T with V_k = (1, u_k, q u_k^2); a line gets A22 = 1 (kept
    # invertible), and every diagonal 1e-12
    a, b, c = s0 + 1e-12, s1, q * s2
    d, e, f = s2 + 1e-12, q * s3, q * s4 + (1.0 - q) + 1e-12
    C00, C01, C02 = d * f - e * e, c * e - b * f, b * e - c * d
    C11, C12, C22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * C00 + b * C01 + c * C02
    inv = [x / det for x in (C00, C01, C02, C11, C12, C22)]
    I00, I01, I02, I11, I12, I22 = inv
    qu2 = q[:, None] * u2[None, :]
    coefs, rss = [], np.zeros(len(w))
    for ev in E:
        ez = ev[zi]
        we = w * ez
        b0, b1, b2 = we @ one, we @ u, q * (we @ u2)
        c0 = I00 * b0 + I01 * b1 + I02 * b2
        c1 = I01 * b0 + I11 * b1 + I12 * b2
        c2 = I02 * b0 + I12 * b1 + I22 * b2
        fit = c0[:, None] + c1[:, None] * u[None, :] + c2[:, None] * qu2
        rss += (w * (ez - fit) ** 2) @ one
        coefs.append(np.stack([c0, c1, c2], 1))
    return coefs, I00, rss


def _local_z(t, ex, ey, ok, fps):
    """z statistic of every sample of one series (time-sorted) against its neighbours.

    `ok`: samples usable as neighbours (valid and not flagged). The neighbour fit is made
    robust to one other glitch among the neighbours (the end of a run of three, a glitch a
    few frames away): when leaving one neighbour out puts that neighbour more than
    NEIGHBOUR_OUT sigma off the others' fit, the fit without it (the one with the lowest
    RSS) is used. Returns z (nan where a sample has too few neighbours to be judged).
    """
    n = len(t)
    offs = np.r_[np.arange(-FAR, -NEAR + 1), np.arange(NEAR, FAR + 1)]
    frame = np.rint((t - t[0]) * fps).astype(np.int64)
    pos = np.full(int(frame[-1]) + 1, -1, np.int64)
    pos[frame] = np.arange(n)
    want = frame[:, None] + offs[None, :]
    inside = (want >= 0) & (want <= frame[-1])
    idx = np.where(inside, pos[np.clip(want, 0, len(pos) - 1)], -1)
    zi = np.clip(idx, 0, n - 1)
    have = (idx >= 0) & ok[zi]
    z = np.empty(n)
    for b0 in range(0, n, _ROWS):  # blocks of samples: the (rows, K) buffers stay in cache
        sl = slice(b0, min(b0 + _ROWS, n))
        z[sl] = _local_z_rows(zi[sl], have[sl], (ex, ey), (ex[sl], ey[sl]), offs)
    return z


_ROWS = 8192  # samples per block of _local_z (8 neighbours: 0.5 MB per (rows, K) buffer)


def _local_z_rows(zi, have, E, E_own, offs):
    """:func:`_local_z` of a block of samples: zi (m, K) their neighbours' positions in the
    series E (ex, ey), have (m, K) the usable ones, E_own the block's own residuals."""
    K = len(offs)
    u = offs / FAR
    left, right = (offs < 0).astype(float), (offs > 0).astype(float)

    def local(hv):
        w = hv.astype(float)
        n_left = np.rint(w @ left).astype(np.int64)  # counts of 0/1: exact
        n_right = np.rint(w @ right).astype(np.int64)
        n_nb = n_left + n_right
        deg = np.where((n_left >= 2) & (n_right >= 2) & (n_nb >= 5), 2, 1)
        q = (deg == 2).astype(float)
        judged = (n_nb >= 3) & (((n_left >= 1) & (n_right >= 1)) | (n_nb >= 4))
        coefs, h, rss = _fit_local(w, u, q, E, zi)
        dof = 2 * (n_nb - (deg + 1))
        return {"q": q, "c": coefs, "h": h, "rss": rss, "dof": dof, "judged": judged}

    cur = local(have)
    for k in range(K):  # drop-one robustness
        hv = have.copy()
        hv[:, k] = False
        alt = local(hv)
        uk = u[k]
        dev2 = sum((e[zi[:, k]] - (c[:, 0] + c[:, 1] * uk + c[:, 2] * (alt["q"] * (uk * uk))))
                   ** 2 for e, c in zip(E, alt["c"]))
        rough = np.maximum(1.0, alt["rss"] / np.maximum(alt["dof"], 1))
        use = (have[:, k] & alt["judged"] & (dev2 > NEIGHBOUR_OUT ** 2 * rough)
               & (alt["rss"] < cur["rss"]))
        if use.any():
            for key in ("h", "rss", "dof", "judged"):
                cur[key] = np.where(use, alt[key], cur[key])
            cur["c"] = [np.where(use[:, None], a, b) for a, b in zip(alt["c"], cur["c"])]
    rough = np.where(cur["dof"] > 0, cur["rss"] / np.maximum(cur["dof"], 1), 1.0)
    ex, ey = E_own
    out2 = (ex - cur["c"][0][:, 0]) ** 2 + (ey - cur["c"][1][:, 0]) ** 2
    z = np.sqrt(out2 / ((1.0 + cur["h"]) * np.maximum(1.0, rough)))
    # a glitch stands off BOTH sides: the edge of a step agrees with the level of one side
    for side in (offs < 0, offs > 0):
        hv = have & side[None, :]
        m = hv.sum(1)
        d2 = sum((e - np.sum(np.where(hv, ea[zi], 0.0), 1) / np.maximum(m, 1)) ** 2
                 for e, ea in zip(E_own, E))
        z_side = np.sqrt(d2 / (1.0 + 1.0 / np.maximum(m, 1)))
        z = np.where(m > 0, np.minimum(z, z_side), z)
    return np.where(cur["judged"], z, np.nan)


def _runs(flag_frames: np.ndarray) -> list:
    """Split sorted frame numbers into runs of consecutive frames."""
    if len(flag_frames) == 0:
        return []
    cut = np.flatnonzero(np.diff(flag_frames) > 1) + 1
    return np.split(np.arange(len(flag_frames)), cut)


def find(res, alpha: float = ALPHA) -> dict:
    """Glitches of a fit: {'lug': bool mask over lug rows, 'body': ..., 'z': {...}, 'c': c}."""
    prob = res.problem
    lay = prob.lay
    fps = float(prob.init_info.get("fps") or 100.0)
    std = standardised_residuals(res)
    n_valid = sum(int(v[2].sum()) for v in std.values())
    c = threshold(n_valid, alpha)
    out = {"c": c, "n": n_valid, "z": {}}
    for role, t_all, idx_all in (("lug", np.asarray(lay.lug_t), np.asarray(lay.lug_i)),
                                 ("body", np.asarray(lay.body_t), np.asarray(lay.body_j))):
        ex, ey, valid = std[role]
        flag = np.zeros(len(t_all), bool)
        zall = np.zeros(len(t_all))
        for m in np.unique(idx_all):
            rows = np.flatnonzero((idx_all == m) & valid)
            if len(rows) < 4:
                continue
            rows = rows[np.argsort(t_all[rows], kind="stable")]
            t = t_all[rows]
            f = np.zeros(len(rows), bool)
            z_at_flag = np.zeros(len(rows))  # each flag's z in the pass that set it
            frame = np.rint((t - t[0]) * fps).astype(np.int64)
            for _ in range(_MAX_PASSES):
                z = _local_z(t, ex[rows], ey[rows], ~f, fps)
                zz = np.where(np.isfinite(z) & ~f, z, 0.0)
                cand = np.flatnonzero(zz > c)
                if len(cand) == 0:
                    break
                # local maxima within FAR frames: the worst of a cluster goes first
                new = [i for i in cand
                       if zz[i] >= zz[np.abs(frame - frame[i]) <= FAR].max()]
                f[new] = True
                z_at_flag[new] = zz[new]
            z = _local_z(t, ex[rows], ey[rows], ~f, fps)
            # a flagged sample's size is the one it was flagged at: once its flagged
            # neighbours leave its local level, that level can move onto it (a structured
            # misfit's flags listed at 0.2-5 sigma under a 5-sigma threshold)
            z = np.where(f, z_at_flag, z)
            on = np.flatnonzero(f)
            for run in _runs(frame[f]):
                if len(run) > MAX_RUN:
                    f[on[run]] = False
            flag[rows] = f
            zall[rows] = np.where(np.isfinite(z), z, 0.0)
        out[role] = flag
        out["z"][role] = zall
    # glitches are independent: flags on COMMON or more markers in one frame (+-1) are a
    # common cause (a lost frame, an image shake), physics or timing, not the tracker's
    tl, tb = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    ft = np.rint(np.r_[tl[out["lug"]], tb[out["body"]]] * fps).astype(np.int64)
    mk = np.r_[np.asarray(lay.lug_i)[out["lug"]], 10_000 + np.asarray(lay.body_j)[out["body"]]]
    if len(ft):
        bad = [f0 for f0 in np.unique(ft)
               if len(np.unique(mk[np.abs(ft - f0) <= 1])) >= COMMON]
        if bad:
            bad = np.array(bad)
            # each flag's deviation from its local level, mm (a common cause moves the
            # markers of a frame alike or by their own speeds; a glitch adds its own jump)
            dev = np.concatenate([np.c_[std[r][0][out[r]], std[r][1][out[r]]]
                                  * float(prob.noise[r]) for r in ("lug", "body")])
            alone = _on_top(ft, mk, dev)
            k = 0
            for role, tt in (("lug", tl), ("body", tb)):
                fr = np.rint(tt * fps).astype(np.int64)
                near = np.any(np.abs(fr[:, None] - bad[None, :]) <= 1, 1)
                on = np.flatnonzero(out[role])
                near[on[alone[k:k + len(on)]]] = False  # a glitch on top of the cause
                k += len(on)
                out[role] = out[role] & ~near
    out["std"] = std
    return out


def _on_top(frames, markers, dev) -> np.ndarray:
    """Flags (frames, markers, deviations in mm) that stand out of the common cause of
    their frame: a deviation further from the other markers' median one (their flags
    within 2 frames) than ON_TOP times the largest of theirs. A lost frame moves each
    marker by its own speed times the frame time (a lug on the top run twice as far as
    the body, one on an arc aslant), a speed controller's hunt each lug along its path
    (the top run against the bottom run), an image shake all alike: within twice the
    largest of them; a tracker's jump to a reflection in the same frame adds its own (a
    contact-dynamics engine's recording, whose misfit flags several markers at once:
    5.0 mm off a common 1.8 mm; a hunting controller's 0.7 mm glitches)."""
    out = np.zeros(len(frames), bool)
    for i in range(len(frames)):
        o = (markers != markers[i]) & (np.abs(frames - frames[i]) <= 2)
        if len(np.unique(markers[o])) < COMMON - 1:
            continue
        m = np.median(dev[o], axis=0)
        out[i] = np.hypot(*(dev[i] - m)) > ON_TOP * np.max(np.hypot(*dev[o].T))
    return out


def listing(res, found: dict) -> list:
    """fit.json `glitches`: [{marker, time_s, dx_mm, dy_mm, size_sigma}], in time order."""
    prob = res.problem
    rec = prob.rec
    out = []
    for role, rows in (("lug", prob.lug_rows), ("body", prob.body_rows)):
        flag = found[role]
        ex, ey, _ = found["std"][role]
        s = float(prob.noise[role])
        for i in np.flatnonzero(flag):
            r = rows[i]
            out.append({"marker": rec.markers[int(rec.marker_index[r])], "role": role,
                        "time_s": float(rec.t[r]), "dx_mm": float(ex[i] * s),
                        "dy_mm": float(ey[i] * s), "size_sigma": float(found["z"][role][i])})
    out.sort(key=lambda g: (g["time_s"], g["marker"]))
    return out

"""A recording and a rig turned into a model layout, observations and a starting point."""

from __future__ import annotations

from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ..model import belt_length, make_layout, param_names, place_knots
from ..model._knots import merge_thin_intervals, top_run_tracks
from ..model._model import BASE_SCALARS, default_params
from ..model.effects import CATALOG
from . import _fragments, _init
from ._checks import MIN_FRAMES
from ._prepare import prepare
from ._noise import estimate_noise

END_FRAMES = 4  # frames with data in each end interval of the speed spline
THIN_FRAMES = 3  # frames (one marker alone: half) each speed interval holds


@dataclass
class Problem:
    """Everything a fit of one recording needs; built by :func:`build_problem`."""

    rec: object  # fitlug.io.Recording
    rig: object  # fitlug.io.Rig
    lay: object  # fitlug.model.Layout
    obs: dict  # lug_x, lug_y, lug_w, body_x, body_y, body_w (jnp arrays; w = valid / sigma)
    lug_ids: list  # marker indices (into rec.markers) of lug index 0..n_lug-1
    body_ids: list
    lug_rows: np.ndarray  # rows of rec for each lug sample of the layout
    body_rows: np.ndarray
    noise: dict  # role -> sigma (mm) used in the weights
    noise_source: str  # 'differences' | 'sigma_mm column' | 'residuals'
    p0: dict  # starting parameters
    init_info: dict = field(default_factory=dict)

    @property
    def n_valid(self) -> int:
        return int(2 * (np.sum(np.asarray(self.obs["lug_w"]) > 0)
                        + np.sum(np.asarray(self.obs["body_w"]) > 0)))

    @property
    def weights(self) -> np.ndarray:
        """Each residual's weight 1 / sigma (0: not a valid sample), in the residuals'
        order: lug x, lug y, body x, body y."""
        return np.concatenate([np.asarray(self.obs[k])
                               for k in ("lug_w", "lug_w", "body_w", "body_w")])

    @property
    def effects(self) -> tuple:
        return self.lay.effects

    def with_effects(self, effects, params: dict | None = None) -> tuple["Problem", dict]:
        """The same problem under another effect set, and params extended with identities."""
        lay = self.lay.with_effects(effects)
        base = dict(self.p0 if params is None else params)
        p = {k: v for k, v in base.items() if k in _BASE_KEYS}
        p.update(default_params(lay))
        p.update({k: v for k, v in base.items() if k in p})
        prob = Problem(**{**self.__dict__, "lay": lay})
        return prob, p


_BASE_KEYS = {"v", *BASE_SCALARS, "sigma0", "cx", "cy"}


def _rows(rec, ids):
    sel = np.isin(rec.marker_index, ids)
    rows = np.flatnonzero(sel)
    return rows


def build_problem(rec, rig, *, effects=(), noise: dict | None = None) -> Problem:
    """Validate a recording for fitting and build its :class:`Problem`.

    `rec` and `rig` may also be a DataFrame / path and a dict / path (as in
    :func:`fitlug.fit`); `effects` a list of catalog ids; `noise` one number (mm) or
    {'lug': , 'body': }.

    Raises InputError (naming the file) for: no body or no lug markers, too few frames,
    fewer valid samples than parameters; TypeError / ValueError for arguments of the
    wrong type or unknown effect ids (naming the valid ones).
    """
    from ..io._coerce import as_recording, as_rig
    from ._boundary import check_effects, check_noise

    effects, noise = check_effects(effects), check_noise(noise)
    rig = as_rig(rig)
    if rig is None:
        from ..io import Rig

        rig = Rig.reference(assumed=True)
    rec = as_recording(rec, rig=rig)
    rec, found = prepare(rec, rig)  # frame, plausibility, swaps, spurious tracks (_prepare)
    path = rec.path
    body_ids, lug_ids = _ids(rec)
    if not body_ids:
        raise InputError(path, "no body markers (role 'body'): the body position X(t) "
                               "cannot be measured")
    if not lug_ids:
        raise InputError(path, "no lug markers (role 'lug'): nothing measures the belt")
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    frames = np.unique(rec.t[valid])
    if len(frames) < MIN_FRAMES:
        raise InputError(path, f"only {len(frames)} frames with valid samples; "
                               f"at least {MIN_FRAMES} are needed")
    fps = _fps(rec, frames)

    t_first = _first_time(rec, valid, fps)
    tX, X, cx, cy = _init.body_reference(rec, body_ids, t_ref=t_first)
    # tracker fragments of one body marker: same offsets, spans that do not overlap
    groups = _fragments.body_groups(body_ids, _fragments.spans_of(rec, body_ids), cx, cy)
    rec, joined = _fragments.apply_groups(rec, groups)
    for j in joined:
        j["reason"] = ("body-marker fragments with the same offsets (c_x, c_y) to within "
                       "3 mm, seen at different times")
    if joined:
        body_ids, lug_ids = _ids(rec)
        tX, X, cx, cy = _init.body_reference(rec, body_ids, t_ref=t_first)
    geom, P, s, sigma0, N, standin, measured = _start_geometry(rec, lug_ids, tX, X,
                                                               rig.lug_pitch_mm)
    # tracker fragments of one lug marker: belt coordinates equal modulo P (a whole
    # number of pitches apart is another lug), spans that do not overlap
    # (only phases read where X is measured: a phase read on the extrapolated X joined a
    # lug seen after the body had left to another, 60-280 mm off at the start)
    groups = _fragments.lug_groups(lug_ids, _fragments.spans_of(rec, lug_ids),
                                   np.where(measured, sigma0, np.nan), P, P / N)
    rec, joined_l = _fragments.apply_groups(rec, groups)
    for j in joined_l:
        j["reason"] = (f"lug-marker fragments whose belt coordinates agree modulo the belt "
                       f"length ({P:.1f} mm) to within 0.3 lug pitch, seen at different times")
    if joined_l:
        body_ids, lug_ids = _ids(rec)
        tX, X, cx, cy = _init.body_reference(rec, body_ids, t_ref=t_first)
        geom, P, s, sigma0, N, standin, _ = _start_geometry(rec, lug_ids, tX, X,
                                                            rig.lug_pitch_mm)
    joined = joined + joined_l
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)

    t_all = rec.t[valid]
    # MODEL.md's gauge: X(0) = 0, sigma_i0 at t = 0; a recording that starts later than
    # its first frame interval takes its first sample as t = 0's stand-in
    t_ref = 0.0 if float(t_all.min()) <= 1.0 / fps + 1e-9 else float(t_all.min())
    t_lo = min(t_ref, float(t_all.min())) - 3.0 / fps
    t_hi = float(t_all.max()) + 3.0 / fps
    tracks = [(rec.t[sel], rec.x[sel]) for sel in
              (valid & (rec.marker_index == m) for m in body_ids)]
    # lug markers on the top run measure the speed where no body marker does (the robot
    # entering or leaving the picture)
    lug_tracks = [(rec.t[sel], rec.x[sel], rec.y[sel]) for sel in
                  (valid & (rec.marker_index == m) for m in lug_ids)]
    aux = top_run_tracks(lug_tracks, top_y=geom["y_off"] + 2 * geom["R"] + geom["e"], slip=s)
    breaks = place_knots(tX, X, t_lo=t_lo, t_hi=t_hi, R=geom["R"], pitch=P / N, slip=s,
                         tracks=tracks, aux_tracks=aux)
    # a clamped cubic B-spline's first and last basis functions live in the first and last
    # knot intervals only: an end interval with no sample in it (the 3-frame margin beyond
    # the last sample can hold a whole ramp-spaced interval) leaves that speed coefficient
    # unconstrained, a zero Jacobian column and NaN standard errors; merge it inward.
    # And an end interval with only a frame or two after the gauge time (the ramp spacing
    # where a robot enters the picture, seen at first by one marker) leaves its
    # coefficient trading with the offsets (X(t) shifted by a constant after it): a null
    # direction of the Jacobian that made effect parameters look unidentifiable. Each end
    # interval holds at least END_FRAMES frames with data besides its end sample.
    frames_v, n_seen = np.unique(t_all, return_counts=True)
    t_first_s, t_last_s = float(t_all.min()), float(t_all.max())
    while len(breaks) > 2 and np.count_nonzero((frames_v >= breaks[-2])
                                               & (frames_v < t_last_s)) < END_FRAMES:
        breaks = np.delete(breaks, -2)
    while len(breaks) > 2 and np.count_nonzero((frames_v > t_first_s)
                                               & (frames_v <= breaks[1])) < END_FRAMES:
        breaks = np.delete(breaks, 1)
    # (a frame where one marker alone is seen counts half: one lug on an arc, the last
    # thing in view as the robot leaves, let the end's ramp-spaced speed swing to 445 mm/s
    # and the slip law to s = 2 between its samples, chi2/dof 2.3 on a null recording;
    # a long end seen by one marker, the robot stopping, keeps its knots)
    breaks = merge_thin_intervals(breaks, frames_v, min_frames=THIN_FRAMES,
                                  weights=np.where(n_seen >= 2, 1.0, 0.5))

    lug_rows = _rows(rec, lug_ids)
    body_rows = _rows(rec, body_ids)
    lug_index = {m: i for i, m in enumerate(lug_ids)}
    body_index = {m: j for j, m in enumerate(body_ids)}
    lay = make_layout(
        breaks=breaks, t_lo=t_lo, t_hi=t_hi, fps=fps, lug_t=rec.t[lug_rows],
        lug_i=np.array([lug_index[m] for m in rec.marker_index[lug_rows]]),
        body_t=rec.t[body_rows],
        body_j=np.array([body_index[m] for m in rec.marker_index[body_rows]]),
        n_lug=len(lug_ids), n_body=len(body_ids), n_belt=N,
        n_contact=rig.lugs_in_contact, L=rig.load_bearing_length_mm, effects=effects,
        t_ref=t_ref)

    # noise: the file's sigma_mm column, else from the data's 4th differences
    if rec.sigma is not None and np.all(np.isfinite(rec.sigma[valid])):
        src = "sigma_mm column"
        sig = np.asarray(rec.sigma, float)
        noise = {r: float(np.median(sig[valid & np.isin(rec.marker_index, ids)]))
                 for r, ids in (("body", body_ids), ("lug", lug_ids))}
        w_l, w_b = 1.0 / sig[lug_rows], 1.0 / sig[body_rows]
    else:
        src = "given" if noise else "differences"
        noise = dict(noise or estimate_noise(rec))
        for role in ("body", "lug"):
            if not np.isfinite(noise.get(role, np.nan)) or noise[role] <= 0:
                from ._noise import irregular_time_stamps

                jitter = irregular_time_stamps(rec.t[valid])
                if jitter:  # the 4th differences need evenly spaced samples
                    raise InputError(path, f"cannot estimate the {role}-marker noise: "
                                           f"{jitter}; give the frames' regular time stamps "
                                           "(frame / fps) or a sigma_mm column")
                raise InputError(path, f"cannot estimate the {role}-marker noise (too few "
                                       "consecutive samples); add a sigma_mm column")
        w_l = np.full(len(lug_rows), 1.0 / noise["lug"])
        w_b = np.full(len(body_rows), 1.0 / noise["body"])
    vl, vb = valid[lug_rows], valid[body_rows]
    obs = {
        "lug_x": np.where(vl, rec.x[lug_rows], 0.0), "lug_y": np.where(vl, rec.y[lug_rows], 0.0),
        "lug_w": np.where(vl, w_l, 0.0),
        "body_x": np.where(vb, rec.x[body_rows], 0.0),
        "body_y": np.where(vb, rec.y[body_rows], 0.0), "body_w": np.where(vb, w_b, 0.0),
    }
    obs = {k: jnp.asarray(v, float) for k, v in obs.items()}

    cx_ref = np.asarray(cx, float)
    coef, cx = _init_speed(lay, obs, cx, standin=standin)
    # the speed spline's X(t_ref) = 0 where no body marker is seen at t_ref (the robot
    # drives into the picture) is its own extrapolation, not the body reference's: the
    # gauge moves by delta (X - delta, offsets + delta). The geometry and phases were read
    # in the body reference's gauge; moved with it (left, x_off and sigma0 were 44 mm off
    # the body offsets on a drive-in seen 1.3 s after the first lug, and LM stopped at
    # chi2/dof 7e5 with the slip 0.14 for 0.083)
    delta = float(np.mean(np.asarray(cx, float) - cx_ref))
    if np.isfinite(delta) and delta != 0.0:
        geom = {**geom, "x_off": float(geom["x_off"]) + delta}
        sigma0 = np.mod(np.asarray(sigma0, float) + delta / (1.0 - s), P)
    p0 = {"v": coef, "s0": s, "beta": 0.0, **geom, "sigma0": sigma0, "cx": cx, "cy": cy}
    p0 = {k: jnp.asarray(v, float) for k, v in p0.items()}
    p0.update(default_params(lay))
    n_par = sum(int(np.size(p0[k])) for k in param_names(lay))
    valid_count = int(2 * vl.sum() + 2 * vb.sum())
    if valid_count <= n_par:
        raise InputError(path, f"fewer valid samples ({valid_count} coordinates) than "
                               f"parameters ({n_par})")
    info = {"fps": fps, "n_belt": N, "breaks": breaks, "geometry0": geom, "slip0": s,
            "joined": joined, "markers": _fragments.coverage(rec, joined), **found}
    return Problem(rec=rec, rig=rig, lay=lay, obs=obs, lug_ids=lug_ids, body_ids=body_ids,
                   lug_rows=lug_rows, body_rows=body_rows, noise=noise, noise_source=src,
                   p0=p0, init_info=info)


def _start_geometry(rec, lug_ids, tX, X, pitch):
    """The data-derived geometry, belt length P, slip, marker phases sigma0 and lug count N."""
    geom, rel = _init.lug_geometry(rec, lug_ids, tX, X)
    P = float(belt_length(geom["R"], geom["D"]))
    inside = _init.measured_samples(rel, tX)
    n_in, n_all = sum(int(k.sum()) for k in inside), sum(len(k) for k in inside)
    standin = (np.zeros(0), np.zeros(0))
    measured = np.ones(len(rel), bool)  # whose phase is read where X is known
    if n_in == n_all or n_in < 0.2 * n_all:
        s, sigma0 = _init.slip_and_phases(rel, geom, tX, X, P)
    else:
        # lug markers seen where no body marker is (the robot driving in or out): the
        # slip and phases read where X is measured, X there found from the lugs
        # (_init.lug_standins), the phases of every marker read on the extended X
        s, sigma0 = _init.slip_and_phases(rel, geom, tX, X, P, inside=inside)
        standin = _init.lug_standins(rec, lug_ids, geom, P, s, sigma0, tX, X)
        ts, Xs = standin
        tX2, X2 = np.concatenate([tX, ts]), np.concatenate([X, Xs])
        order = np.argsort(tX2, kind="stable")
        tX2, X2 = tX2[order], X2[order]
        known = np.round(ts * 1e6).astype(np.int64)
        rel2, inside2 = [], []
        for (m, t, xr, y), k in zip(rel, inside):
            xr2 = xr + _init.X_at(t, tX, X) - _init.X_at(t, tX2, X2)
            rel2.append((m, t, xr2, y))
            inside2.append(k | np.isin(np.round(t * 1e6).astype(np.int64), known))
        _, sigma0 = _init.slip_and_phases(rel2, geom, tX2, X2, P, inside=inside2, s=s)
        measured = np.isfinite(sigma0)
        if not np.all(measured):  # seen only where X is extrapolated
            _, every = _init.slip_and_phases(rel2, geom, tX2, X2, P, s=s)
            sigma0 = np.where(np.isfinite(sigma0), sigma0, every)
    return geom, P, s, sigma0, _init.infer_n_belt(P, pitch, sigma0), standin, measured


def _ids(rec):
    """(body, lug) marker indices, without tracker fragments of a single valid sample
    (they measure nothing a fit could use; a marker never found stays, and is refused)."""
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    n = np.bincount(rec.marker_index[valid], minlength=rec.n_markers)
    return ([m for m, r in enumerate(rec.roles) if r == "body" and n[m] != 1],
            [m for m, r in enumerate(rec.roles) if r == "lug" and n[m] != 1])


def _first_time(rec, valid, fps):
    t0 = float(rec.t[valid].min())
    return 0.0 if t0 <= 1.0 / fps + 1e-9 else t0


def _fps(rec, frames):
    fps = None
    try:
        fps = float(rec.meta.get("fps")) if rec.meta.get("fps") else None
    except (TypeError, ValueError):
        fps = None
    if not fps or not np.isfinite(fps) or fps <= 0:
        d = np.diff(frames)
        fps = 1.0 / float(np.median(d[d > 0]))
    return fps


def _init_speed(lay, obs, cx0, standin=None):
    """Speed-spline coefficients and cx by linear least squares on the body x samples.

    `standin`: (t, X) found from the lug markers where no body marker is seen
    (:func:`_init.lug_standins`, in the gauge of the offsets `cx0`), taken as samples of
    the first body marker at a tenth of its weight: a robot driving in shows its front arc
    for a second or more before any body marker, and the speed there was otherwise the
    spline's extrapolation of the first body samples (a drive-in seen 1.3 s before its body,
    at rest and then in its ramp, ended at chi2/dof 7e5 with the slip 0.14 for 0.083)."""
    ts, Xs = (np.zeros(0), np.zeros(0)) if standin is None else standin
    j0 = int(np.flatnonzero(np.isfinite(cx0))[0]) if np.isfinite(cx0).any() else 0
    w_b = np.asarray(obs["body_w"])
    w_s = 0.1 * float(np.median(w_b[w_b > 0])) if (w_b > 0).any() else 0.0
    if len(ts) and w_s > 0:
        obs = {**obs, "body_x": np.concatenate([np.asarray(obs["body_x"]), Xs + cx0[j0]]),
               "body_w": np.concatenate([w_b, np.full(len(ts), w_s)])}
        lay_t = np.concatenate([np.asarray(lay.body_t), ts])
        lay_j = np.concatenate([np.asarray(lay.body_j), np.full(len(ts), j0)])
    else:
        lay_t, lay_j = np.asarray(lay.body_t), np.asarray(lay.body_j)
    if lay.grid.shape[0] * lay.n_coef > _DENSE_INIT_ENTRIES:  # long recordings: by chunks
        from ..model._model import fit_body_speed

        return fit_body_speed(lay, lay_t, lay_j, obs["body_x"], obs["body_w"],
                              smooth=SPEED_START_SMOOTH)
    Bn, _, Bm, _ = lay.dense_bases()
    h = float(lay.h)
    # integrated basis at nodes (Simpson, cumulative), then Hermite at the body times
    I = np.vstack([np.zeros(Bn.shape[1]), np.cumsum(h / 6 * (Bn[:-1] + 4 * Bm + Bn[1:]), 0)])  # noqa: E741
    grid = np.asarray(lay.grid)

    def herm(t):
        u = (t - grid[0]) / h
        i = np.clip(np.floor(u).astype(int), 0, len(grid) - 2)
        tau = (u - i)[:, None]
        t2, t3 = tau * tau, tau ** 3
        return ((2 * t3 - 3 * t2 + 1) * I[i] + (t3 - 2 * t2 + tau) * h * Bn[i]
                + (-2 * t3 + 3 * t2) * I[i + 1] + (t3 - t2) * h * Bn[i + 1])

    A = herm(lay_t) - herm(np.full(1, float(lay.t_ref)))
    w = np.asarray(obs["body_w"])
    C = np.zeros((len(lay_t), lay.n_body))
    C[np.arange(len(lay_t)), lay_j] = 1.0
    M = np.hstack([A, C]) * w[:, None]
    # body positions fix only the integral of the speed: where no body marker is seen for a
    # few knot intervals (one has left the picture, the other is occluded) the coefficients
    # there were free to cancel in pairs (+-3e7 mm/s, seen in bench_realism's fov row); a
    # weak curvature penalty (1 unit of chi per SPEED_START_SMOOTH mm/s of second
    # difference, against ~10 per mm/s that one body sample carries) interpolates the gap
    from ..model._model import second_differences

    K = A.shape[1]
    D2 = np.hstack([second_differences(K), np.zeros((max(K - 2, 0), lay.n_body))])
    M = np.vstack([M, D2 / SPEED_START_SMOOTH])
    rhs = np.concatenate([np.asarray(obs["body_x"]) * w, np.zeros(D2.shape[0])])
    sol = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return sol[:K], sol[K:]


SPEED_START_SMOOTH = 10.0  # mm/s of second difference of the start's speed coefficients


_DENSE_INIT_ENTRIES = 4_000_000  # (G, K) basis entries above which _init_speed chunks


def effect_ids(effects) -> tuple:
    return tuple(e for e in CATALOG if e in set(effects))

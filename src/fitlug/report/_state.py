"""DIR/state.npz: every array the report draws, so `fit-lug report DIR` needs no refit.

The file holds plain numpy arrays (no pickles) plus one JSON string `meta`. Keys:

- lug_t, lug_i, lug_x, lug_y, lug_valid, lug_model_x, lug_model_y, lug_seg, lug_u
  (per lug sample: time s, marker index, data and model mm, path segment 0-3, belt
  coordinate mod P, mm); body_t, body_j, body_x, body_y, body_valid, body_model_x,
  body_model_y; residuals are data - model (mm) where valid, NaN elsewhere:
  lug_res_x, lug_res_y, body_res_x, body_res_y;
- curve_t, curve_i, curve_x, curve_y: the model's lug paths on a 4x finer time grid;
- fine_t, fine_X, fine_v, fine_psi, fine_vt, fine_s: kinematics on a fine grid (mm, mm/s);
  fine_s holds a slip-law family term (fine_s_linear: the linear law's part, then);
- body_X_data: body reference position from each body sample (x - c_x), mm;
- post_samples (n, k) and post_names in meta, when a posterior is given; post_chain
  (draws, walkers) of the first sampled parameter, for a trace plot;
- base_lug_res_x/y, base_body_res_x/y: residuals before the explanation's effects;
- lsq_corr (k, k) with corr_names in meta: correlation of the least-squares fit's scalar
  parameters (physical and effect ones).
"""

from __future__ import annotations

import io
import json
import os

import numpy as np

STATE_FILE = "state.npz"
FINE_POINTS = 2000
CURVE_OVERSAMPLE = 4
MAX_SAMPLES = 40000
#: points per lug marker of the model curves at most: a long recording's curves are drawn
#: at a coarser step than CURVE_OVERSAMPLE per frame (memory and drawing time bounded)
MAX_CURVE_POINTS = 20000


def _raw_residuals(prob, p, model=None):
    """Data minus model (mm) per role and axis, NaN where the sample is missing.

    model: the model positions (lug_x, lug_y, body_x, body_y) when already evaluated."""
    if model is None:
        from .. import _exported

        from ..fit._buckets import pad_model
        from ..model._host import predict_host

        # through a module exported to disk: a new process skips its tracing; on bucketed
        # shapes (a recording of a new length compiles nothing new), cut back
        pm = pad_model(p, prob.lay)
        model = _exported.call("report_predict", predict_host, (), *(pm or (p, prob.lay)))
        Sl, Sb = prob.lay.lug_t.shape[0], prob.lay.body_t.shape[0]
        model = tuple(np.asarray(v)[:n] for v, n in zip(model, (Sl, Sl, Sb, Sb)))
    lx, ly, bx, by = (np.asarray(a) for a in model)
    o = {k: np.asarray(v) for k, v in prob.obs.items()}
    vl, vb = o["lug_w"] > 0, o["body_w"] > 0
    nan = np.nan
    return {"lug_model_x": lx, "lug_model_y": ly, "body_model_x": bx, "body_model_y": by,
            "lug_res_x": np.where(vl, o["lug_x"] - lx, nan),
            "lug_res_y": np.where(vl, o["lug_y"] - ly, nan),
            "body_res_x": np.where(vb, o["body_x"] - bx, nan),
            "body_res_y": np.where(vb, o["body_y"] - by, nan)}


_JITTED = {}


def _model_state(p, lay, fine, lay_c):
    """Every model array of the state in one compiled call: positions at the samples,
    path segments, belt travel at the lug samples, kinematics on the fine grid, the lug
    curves (positions on lay_c) and the belt length."""
    from ..model import belt_length, kinematics, predict, segments
    from ..model._model import _true_times  # frame_drop: psi at the true times

    kin = kinematics(p, lay, fine)
    return {"model": predict(p, lay), "seg": segments(p, lay),
            "psi_l": kinematics(p, lay, _true_times(p, lay, lay.lug_t))["psi"],
            "fine": {k: kin[k] for k in ("X", "v", "psi", "v_t", "s")},
            "curve": predict(p, lay_c)[:2], "P": belt_length(p["R"], p["D"])}


_FINE = ("X", "v", "psi", "v_t", "s")


def _model_state_flat(p, lay, fine, lay_c):
    """:func:`_model_state` as a flat tuple of arrays (what an exported module returns)."""
    m = _model_state(p, lay, fine, lay_c)
    return (*m["model"], m["seg"], m["psi_l"], *(m["fine"][k] for k in _FINE), *m["curve"],
            m["P"])


def _model_state_jit():
    if "state" not in _JITTED:
        import equinox as eqx

        _JITTED["state"] = eqx.filter_jit(_model_state_flat)
    return _JITTED["state"]


def _model_state_call(p, lay, fine, lay_c) -> dict:
    """:func:`_model_state`, compiled, through a module exported to disk (a new process
    skips tracing and lowering it: about 0.7 s of every warm run)."""
    from .. import _exported
    from ..fit._buckets import pad_model

    # on bucketed shapes (a recording of a new length compiles nothing new), cut back
    pm, pc = pad_model(p, lay), pad_model(p, lay_c, like=lay)
    if pm is not None and pc is not None:
        out = _exported.call("report_state", _model_state_jit(), (), pm[0], pm[1], fine,
                             pc[1])
    else:
        out = _exported.call("report_state", _model_state_jit(), (), p, lay, fine, lay_c)
    Sl, Sb, Sc = lay.lug_t.shape[0], lay.body_t.shape[0], lay_c.lug_t.shape[0]
    out = [np.asarray(v) for v in out]
    model = [v[:n] for v, n in zip(out[:4], (Sl, Sl, Sb, Sb))]
    seg, psi_l, rest = out[4][:Sl], out[5][:Sl], out[6:]
    fine_d = dict(zip(_FINE, rest[:len(_FINE)]))
    cx, cy, P = rest[len(_FINE):]
    cx, cy = cx[:Sc], cy[:Sc]
    return {"model": tuple(model), "seg": seg, "psi_l": psi_l, "fine": fine_d,
            "curve": (cx, cy), "P": P}


def state_arrays(res, posterior=None, explanation=None) -> tuple[dict, dict]:
    """(arrays, meta) of a fit, its posterior and explanation (see the module docstring)."""
    # float64 before any array; imported here, not at the top: load_state and the report's
    # rendering need no JAX (fitlug.report._aside renders in a process without it)
    from .. import _jaxconfig  # noqa: F401

    import jax

    prob, lay = res.problem, res.problem.lay
    p = {k: jax.device_put(np.asarray(v)) for k, v in res.params.items()}  # no compile
    o = {k: np.asarray(v) for k, v in prob.obs.items()}
    a = {"lug_t": np.asarray(lay.lug_t), "lug_i": np.asarray(lay.lug_i),
         "lug_x": o["lug_x"], "lug_y": o["lug_y"], "lug_valid": o["lug_w"] > 0,
         "body_t": np.asarray(lay.body_t), "body_j": np.asarray(lay.body_j),
         "body_x": o["body_x"], "body_y": o["body_y"], "body_valid": o["body_w"] > 0}
    t_lo = float(min(a["lug_t"].min(), a["body_t"].min()))
    t_hi = float(max(a["lug_t"].max(), a["body_t"].max()))
    fine = np.linspace(t_lo, t_hi, FINE_POINTS)
    # the model's lug paths between frames, for smooth curves
    dt = np.median(np.diff(np.unique(a["lug_t"]))) / CURVE_OVERSAMPLE
    dt = max(dt, (t_hi - t_lo) / MAX_CURVE_POINTS)
    ct = np.arange(t_lo, t_hi + dt / 2, dt)
    ci = np.repeat(np.arange(lay.n_lug), len(ct))
    ct = np.tile(ct, lay.n_lug)
    lay_c = lay.with_times(ct, ci, np.asarray(lay.body_t)[:1], np.asarray(lay.body_j)[:1])
    m = _model_state_call(p, lay, jax.device_put(fine), lay_c)

    a.update(_raw_residuals(prob, p, m["model"]))
    a["lug_seg"] = np.asarray(m["seg"]).astype(np.int8)
    P = float(m["P"])
    a["lug_u"] = np.mod(np.asarray(p["sigma0"])[a["lug_i"]] + np.asarray(m["psi_l"]), P)
    kin = m["fine"]
    a.update({"fine_t": fine, "fine_X": np.asarray(kin["X"]), "fine_v": np.asarray(kin["v"]),
              "fine_psi": np.asarray(kin["psi"]), "fine_vt": np.asarray(kin["v_t"]),
              "fine_s": np.asarray(kin["s"])})
    law = ((getattr(res, "robust", None) or {}).get("slip_term") or {}).get("law")
    if law:  # a slip-law family term (fitlug.explain.families): the model's slip holds it
        from ..explain.families._slip import slip_change

        s0 = float(res.robust["slip_term"]["steady_slip"])
        a["fine_s_linear"] = a["fine_s"]
        a["fine_s"] = a["fine_s"] + slip_change(law, a["fine_v"], a["fine_s"], s0)
    a["body_X_data"] = a["body_x"] - np.asarray(p["cx"])[a["body_j"]]
    cx, cy = m["curve"]
    a.update({"curve_t": ct, "curve_i": ci, "curve_x": np.asarray(cx), "curve_y": np.asarray(cy)})

    meta = {"markers": list(prob.rec.markers), "lug_ids": [int(m) for m in prob.lug_ids],
            "body_ids": [int(m) for m in prob.body_ids], "effects": list(res.effects),
            "belt_length_mm": P, "n_belt": int(lay.n_belt), "n_contact": int(lay.n_contact),
            "L_mm": float(lay.L), "noise_mm": {k: float(v) for k, v in prob.noise.items()},
            "mass_kg": prob.rig.mass_kg, "chi2_per_dof": float(res.chi2_per_dof),
            "least_squares": {k: e.as_dict() for k, e in res.quantities.items()},
            "slip_law_term": ({**law, "steady_slip": float(res.robust["slip_term"][
                "steady_slip"])} if law else None)}
    corr = _scalar_correlation(res)
    if corr is not None:
        meta["corr_names"], a["lsq_corr"] = corr

    if explanation is not None and getattr(explanation, "base", None) is not None:
        base = explanation.base
        if len(np.asarray(base.problem.lay.lug_t)) == len(a["lug_t"]):
            rb = _raw_residuals(base.problem, {k: jax.device_put(np.asarray(v))
                                                for k, v in base.params.items()})
            a.update({f"base_{k}": rb[k] for k in ("lug_res_x", "lug_res_y", "body_res_x",
                                                   "body_res_y")})
            meta["base_effects"] = list(base.effects)
            meta["base_chi2_per_dof"] = float(base.chi2_per_dof)
    if posterior is not None:
        add_posterior(a, meta, posterior)
    return a, meta


def add_posterior(arrays: dict, meta: dict, posterior) -> None:
    """Put a posterior's arrays (post_samples, post_chain) and names into the (arrays,
    meta) of :func:`state_arrays` made without it."""
    names = [k for k in posterior.samples]
    S = np.column_stack([np.asarray(posterior.samples[k], float) for k in names])
    if len(S) > MAX_SAMPLES:  # thin evenly: the report needs shapes, not every draw
        S = S[np.linspace(0, len(S) - 1, MAX_SAMPLES).astype(int)]
    arrays["post_samples"] = S
    arrays["post_chain"] = np.asarray(posterior.chain.samples[..., 0])
    meta["post_names"] = names
    meta["post_parameters"] = list(posterior.parameters)


def _scalar_correlation(res):
    """(names, correlation) of the least-squares fit's scalar parameters (physical and
    effect ones; per-marker and spline parameters left out), or None."""
    try:
        sl = res.packing.slices()
        cov = np.asarray(res.cov, float)
    except (AttributeError, TypeError, ValueError):
        return None
    names = [k for k, s in sl.items() if s.stop - s.start == 1]
    if len(names) < 2 or cov.ndim != 2:
        return None
    idx = [sl[k].start for k in names]
    C = cov[np.ix_(idx, idx)]
    d = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    return names, C / np.outer(d, d)


def save_state(out_dir, res, posterior=None, explanation=None, run_id=None) -> str:
    """Write DIR/state.npz for the report (atomically); returns its path.

    run_id: the id of the run that writes the folder (fit.json `run_id`), kept in the
    meta so that `write_report` refuses a fit.json and state.npz of different runs.

    res: the final FitResult; posterior: a fitlug.posterior.Posterior or None; explanation: an
    object with `.base` (the FitResult before any effects) or None.
    """
    arrays, meta = state_arrays(res, posterior, explanation)
    return write_state(out_dir, arrays, meta, run_id)


def write_state(out_dir, arrays: dict, meta: dict, run_id=None, compressed: bool = True) -> str:
    """Write (arrays, meta) of :func:`state_arrays` as DIR/state.npz (atomically); returns
    its path. `meta` gains the run id. compressed=False: a scratch copy, fast to write."""
    from ..io import write_bytes_atomic

    meta = dict(meta)
    if run_id is not None:
        meta["run_id"] = str(run_id)
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, meta=np.array(json.dumps(meta)),
                                                      **arrays)
    path = os.path.join(os.fspath(out_dir), STATE_FILE)
    write_bytes_atomic(path, buf.getvalue())
    return path


def load_state(out_dir) -> dict:
    """Read DIR/state.npz into a dict of arrays, with 'meta' decoded.

    Raises InputError when the file is missing or unreadable.
    """
    import zipfile
    import zlib

    from .._errors import InputError

    path = os.path.join(os.fspath(out_dir), STATE_FILE)
    if not os.path.isfile(path):
        raise InputError(path, "no state.npz in the fit folder (was it written by `fit-lug` "
                               "with the report enabled?)")
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
        out["meta"] = json.loads(str(out["meta"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        # a truncated or damaged file (an interrupted copy, a full disk): one line, no traceback
        raise InputError(path, f"unreadable state file, truncated or damaged ({exc}); rerun "
                               "`fit-lug` on the recording to rewrite the folder") from None
    return out

"""A FitResult's numbers with their names: the covariance and correlation of the fitted
parameters as labelled tables, the residuals by marker and axis (raw in mm and
standardised), a short repr and a compact HTML table for notebooks.

Element labels: a scalar parameter by its name (``R``), an array one by name and index
(``v[3]``, ``cx[1]``; element i of ``sigma0`` is lug marker ``problem.lug_ids[i]``, of
``cx``/``cy`` body marker ``problem.body_ids[i]``, as in :class:`fitlug.Parameters`).
"""

from __future__ import annotations

import html

import numpy as np


def labels(res) -> list[str]:
    """One label per element of the free vector (packing order, held elements included)."""
    out = []
    for k, shape, n in zip(res.packing.names, res.packing.shapes, res.packing.sizes):
        out += [k] if not shape else [f"{k}[{i}]" for i in range(n)]
    return out


def covariance_frame(res):
    """The covariance of the fitted parameters as a pandas DataFrame labelled both ways
    (units: the parameters', e.g. mm^2 for R; held elements: rows and columns of 0)."""
    import pandas as pd

    names = labels(res)
    return pd.DataFrame(np.asarray(res.cov), index=names, columns=names)


def correlation_frame(res):
    """The correlation matrix (NaN rows and columns for held or non-acting elements)."""
    import pandas as pd

    c = np.asarray(res.cov, float)
    d = np.sqrt(np.maximum(np.diag(c), 0.0))
    with np.errstate(all="ignore"):
        r = c / np.outer(d, d)
    r[d == 0, :] = np.nan
    r[:, d == 0] = np.nan
    names = labels(res)
    return pd.DataFrame(r, index=names, columns=names)


def residual_arrays(res) -> dict:
    """{marker: {'t': (n,), 'x': (n,), 'y': (n,), 'x_std': , 'y_std': }}: per marker the
    sample times (s), the raw residuals model - data (mm, NaN where a sample has no weight:
    missing or kept out as a glitch) and the standardised ones (raw / sigma)."""
    df = residuals_frame(res)
    out = {}
    for m, g in df.groupby("marker", sort=False):
        gx, gy = g[g["axis"] == "x"], g[g["axis"] == "y"]
        out[m] = {"role": g["role"].iloc[0], "t": gx["time_s"].to_numpy(),
                  "x": gx["raw_mm"].to_numpy(), "y": gy["raw_mm"].to_numpy(),
                  "x_std": gx["standardised"].to_numpy(), "y_std": gy["standardised"].to_numpy()}
    return out


def residuals_frame(res):
    """The residuals as a tidy pandas DataFrame, one row per sample and axis: time_s,
    marker, role, axis ('x'/'y'), raw_mm (model - data, mm), standardised (raw / sigma,
    what the fit minimised), sigma_mm, used (False: a missing sample or a glitch kept
    out with zero weight; then raw_mm and standardised are NaN)."""
    import pandas as pd

    prob = res.problem
    rec = prob.rec
    r = np.asarray(res.residuals, float)
    S_l, S_b = len(prob.lug_rows), len(prob.body_rows)
    parts = []
    off = 0
    for role, rows, wkey, n in (("lug", prob.lug_rows, "lug_w", S_l),
                                ("body", prob.body_rows, "body_w", S_b)):
        w = np.asarray(prob.obs[wkey], float)
        mk = np.asarray(rec.markers, dtype=object)[np.asarray(rec.marker_index)[rows]]
        for axis in ("x", "y"):
            rr = r[off:off + n]
            off += n
            used = w > 0
            sig = np.where(used, 1.0 / np.where(used, w, 1.0), np.nan)
            parts.append(pd.DataFrame({
                "time_s": np.asarray(rec.t, float)[rows], "marker": mk, "role": role,
                "axis": axis, "raw_mm": np.where(used, rr * sig, np.nan),
                "standardised": np.where(used, rr, np.nan), "sigma_mm": sig, "used": used}))
    return pd.concat(parts, ignore_index=True)


def short_repr(res) -> str:
    """One line: effects, slip, chi^2/dof, parameters (held), convergence."""
    s = res.quantities.get("slip")
    slip = "n/a" if s is None or s.value is None else f"{s.value:.6g} ± {s.std:.2g}"
    held = 0 if res.held is None else int(np.sum(res.held))
    rec = res.problem.rec
    name = rec.path or "recording"
    return (f"<FitResult {name}: slip {slip}, chi2/dof {res.chi2_per_dof:.4g}, "
            f"effects: {', '.join(res.effects) or 'none'}, {res.n_params} free parameters"
            + (f" ({held} held)" if held else "") + f", {res.n_data} data, "
            + ("converged" if res.converged else "NOT converged") + ">")


_ROWS = (("slip", "slip s0", ""), ("delta_l_mm", "lug deflection Δl'", "mm"),
         ("stiffness_N_per_mm", "lug stiffness k", "N/mm"),
         ("rolling_resistance", "rolling resistance C_rr", ""), ("k_over_m", "k / m", "N/(mm kg)"),
         ("R_mm", "wheel radius R", "mm"), ("D_mm", "wheel spacing D", "mm"),
         ("e_mm", "lug height e", "mm"))


def html_table(res) -> str:
    """A compact HTML table of the headline quantities (notebook display)."""
    rows = []
    for key, label, unit in _ROWS:
        e = res.quantities.get(key)
        if e is None or e.value is None:
            continue
        rows.append(f"<tr><td>{html.escape(label)}</td><td>{e.value:.6g}</td>"
                    f"<td>{e.std:.2g}</td><td>{unit}</td></tr>")
    head = html.escape(short_repr(res)[1:-1])
    return (f"<div><b>{head}</b><table><tr><th>quantity</th><th>value</th><th>± 1σ</th>"
            f"<th>unit</th></tr>{''.join(rows)}</table></div>")

"""The fitted model as a function of time: marker positions and the slip s(t) at any
instants of the recording, with delta-method bands from the fit's covariance.

Used through :meth:`FitResult.predict` and :meth:`FitResult.slip_at`. The query times
are padded to a bucket of sizes (powers of two from 64), so that calls with other times
or markers reuse one compiled program per result (the layout's grid and effects fixed).
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..model import kinematics, make_layout, predict as model_predict

Z95 = 1.959963984540054
CHUNK = 256  # samples of each role per compiled evaluation
MOVING = 0.05  # the slip is defined where the body moves faster than this share of its peak


@dataclasses.dataclass(frozen=True)
class Band:
    """A quantity over time with its 1 σ band (delta method from the fit's covariance).

    Attributes:
        t: times, s (T,).
        value: the model's value at t (T,); NaN where undefined.
        std: its standard error (T,).
    """

    t: np.ndarray
    value: np.ndarray
    std: np.ndarray

    @property
    def ci95(self) -> tuple[np.ndarray, np.ndarray]:
        """The pointwise 95 % interval (lo, hi) of a normal error."""
        return self.value - Z95 * self.std, self.value + Z95 * self.std

    def to_dataframe(self, name: str = "value"):
        """A pandas DataFrame with columns t_s, `name`, std."""
        import pandas as pd

        return pd.DataFrame({"t_s": self.t, name: self.value, "std": self.std})


@dataclasses.dataclass(frozen=True)
class Prediction:
    """Model positions of markers at given times, with their 1 σ bands.

    Attributes:
        t: times, s (T,).
        markers: marker names (M,), in the recording's spelling.
        roles: "lug" or "body" per marker (M,).
        x, y: positions, mm (M, T).
        x_std, y_std: their standard errors from the fit's covariance, mm (M, T).
    """

    t: np.ndarray
    markers: tuple
    roles: tuple
    x: np.ndarray
    y: np.ndarray
    x_std: np.ndarray
    y_std: np.ndarray

    def __getitem__(self, marker: str) -> dict:
        """{"x", "y", "x_std", "y_std"} of one marker (arrays over t)."""
        if marker not in self.markers:
            raise KeyError(f"marker {marker!r} not predicted; markers: {', '.join(self.markers)}")
        i = self.markers.index(marker)
        return {"x": self.x[i], "y": self.y[i], "x_std": self.x_std[i], "y_std": self.y_std[i]}

    def to_dataframe(self):
        """A tidy pandas DataFrame: one row per marker and time (marker, role, t_s, x_mm,
        y_mm, x_std_mm, y_std_mm)."""
        import pandas as pd

        M, T = self.x.shape
        return pd.DataFrame({
            "marker": np.repeat(self.markers, T), "role": np.repeat(self.roles, T),
            "t_s": np.tile(self.t, M), "x_mm": self.x.ravel(), "y_mm": self.y.ravel(),
            "x_std_mm": self.x_std.ravel(), "y_std_mm": self.y_std.ravel()})


def _bucket(n: int) -> int:
    return max(64, 1 << int(np.ceil(np.log2(max(n, 1)))))


def _pad(a, n, fill):
    a = np.asarray(a)
    return np.concatenate([a, np.full(n - len(a), fill, a.dtype)])


@partial(jax.jit, static_argnums=(3,))
def _positions(flat, fixed, lay, packing):
    def f(fl):
        return jnp.concatenate(model_predict(packing.unpack(fl, fixed), lay))

    return f(flat), jax.jacfwd(f)(flat)


@partial(jax.jit, static_argnums=(4,))
def _slip(flat, fixed, lay, t, packing):
    def f(fl):
        k = kinematics(packing.unpack(fl, fixed), lay, t)
        return k["s"], k["v"]

    (s, v), (J, _) = f(flat), jax.jacfwd(f)(flat)
    # the peak speed over the fitted span (the fit's own grid), for "moving"
    from ..model import integrate

    vn = integrate(packing.unpack(flat, fixed), lay)[2]
    return s, v, J, jnp.max(jnp.abs(vn))


def _std(J, cov) -> np.ndarray:
    J = np.asarray(J)
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))


def _span(res) -> tuple[float, float]:
    prob = res.problem
    rows = np.r_[prob.lug_rows, prob.body_rows].astype(int)
    t = np.asarray(prob.rec.t)[rows]
    return float(np.min(t)), float(np.max(t))


def _layout_for(res, t: np.ndarray, extrapolate: bool):
    """The fit's layout (same grid: one compiled program) or, extrapolating beyond its
    grid, one on a grid extended by whole steps (speed held at the edge knots')."""
    t = np.asarray(t, float)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)):
        raise ValueError("times must be a non-empty 1-D array of finite seconds")
    lo, hi = _span(res)
    lay = res.problem.lay
    if t.min() < lo - 1e-9 or t.max() > hi + 1e-9:
        if not extrapolate:
            raise ValueError(f"times {t.min():.6g}..{t.max():.6g} s reach outside the recording "
                             f"({lo:.6g}..{hi:.6g} s); pass extrapolate=True to evaluate the "
                             "model there (speed and acceleration held at the edge of the fit)")
        g = np.asarray(lay.grid)
        h = float(lay.h)
        if t.min() < g[0] or t.max() > g[-1]:
            t_lo = g[0] - h * np.ceil(max(g[0] - t.min(), 0.0) / h + 1)
            t_hi = g[-1] + h * np.ceil(max(t.max() - g[-1], 0.0) / h + 1)
            new = make_layout(breaks=np.asarray(lay.breaks), t_lo=t_lo, t_hi=t_hi, fps=1.0 / h,
                              substeps=1, lug_t=lay.lug_t, lug_i=lay.lug_i, body_t=lay.body_t,
                              body_j=lay.body_j, n_lug=lay.n_lug, n_body=lay.n_body,
                              n_belt=lay.n_belt, n_contact=lay.n_contact, L=lay.L,
                              effects=lay.effects, t_ref=float(lay.t_ref))
            lay = new
    return lay


def _fixed(res) -> dict:
    return {k: jnp.asarray(v, float) for k, v in res.params.items()
            if k not in res.packing.names}


def predict_positions(res, times, markers=None, *, extrapolate: bool = False) -> Prediction:
    """See :meth:`fitlug.fit.FitResult.predict`."""
    prob = res.problem
    t = np.atleast_1d(np.asarray(times, float))
    lay = _layout_for(res, t, extrapolate)
    names = list(prob.rec.markers)
    fitted = [names[m] for m in prob.lug_ids] + [names[m] for m in prob.body_ids]
    if markers is None:
        markers = fitted
    elif isinstance(markers, str):
        markers = [markers]
    markers = list(markers)
    bad = [m for m in markers if m not in fitted]
    if bad:
        raise ValueError(f"unknown marker(s) {', '.join(map(repr, bad))}; fitted markers: "
                         f"{', '.join(fitted)}")
    lug_of = {names[m]: i for i, m in enumerate(prob.lug_ids)}
    body_of = {names[m]: j for j, m in enumerate(prob.body_ids)}
    lm = [m for m in markers if m in lug_of]
    bm = [m for m in markers if m in body_of]
    T = len(t)
    lug_t, lug_i = np.tile(t, len(lm)), np.repeat([lug_of[m] for m in lm], T).astype(np.int64)
    body_t = np.tile(t, len(bm))
    body_j = np.repeat([body_of[m] for m in bm], T).astype(np.int64)
    nl, nb = len(lug_t), len(body_t)
    # fixed chunks of samples (padded with the first time): one compiled program per
    # result whatever the times and markers asked for
    CL = CHUNK if prob.lay.n_lug else 0
    CB = CHUNK if prob.lay.n_body else 0
    n_chunks = max(1, -(-nl // CHUNK), -(-nb // CHUNK))
    fixed, flat, cov = _fixed(res), jnp.asarray(res.flat), np.asarray(res.cov)
    out = {k: [] for k in ("lx", "ly", "bx", "by", "slx", "sly", "sbx", "sby")}
    for c in range(n_chunks):
        a = slice(c * CHUNK, (c + 1) * CHUNK)
        lt, li, bt, bj = lug_t[a], lug_i[a], body_t[a], body_j[a]
        kl, kb = len(lt), len(bt)
        q = lay.with_times(_pad(lt, CL, t[0]), _pad(li, CL, 0), _pad(bt, CB, t[0]),
                           _pad(bj, CB, 0))
        y, J = _positions(flat, fixed, q, res.packing)
        y, sd = np.asarray(y), _std(J, cov)
        for key, arr in (("", y), ("s", sd)):
            out[key + "lx"].append(arr[:kl])
            out[key + "ly"].append(arr[CL:CL + kl])
            out[key + "bx"].append(arr[2 * CL:2 * CL + kb])
            out[key + "by"].append(arr[2 * CL + CB:2 * CL + CB + kb])
    lx, ly, bx, by, slx, sly, sbx, sby = (np.concatenate(v) for v in out.values())
    x = np.concatenate([lx.reshape(len(lm), T), bx.reshape(len(bm), T)])
    yy = np.concatenate([ly.reshape(len(lm), T), by.reshape(len(bm), T)])
    xs = np.concatenate([slx.reshape(len(lm), T), sbx.reshape(len(bm), T)])
    ys = np.concatenate([sly.reshape(len(lm), T), sby.reshape(len(bm), T)])
    order = [(lm + bm).index(m) for m in markers]
    return Prediction(t=t, markers=tuple(markers),
                      roles=tuple("lug" if m in lug_of else "body" for m in markers),
                      x=x[order], y=yy[order], x_std=xs[order], y_std=ys[order])


def slip_at(res, times, *, extrapolate: bool = False) -> Band:
    """See :meth:`fitlug.fit.FitResult.slip_at`."""
    t = np.atleast_1d(np.asarray(times, float))
    lay = _layout_for(res, t, extrapolate)
    n = len(t)
    tq = jnp.asarray(_pad(t, _bucket(n), t[0]))
    s, v, J, vmax = _slip(jnp.asarray(res.flat), _fixed(res), lay, tq, res.packing)
    s, v = np.asarray(s)[:n], np.asarray(v)[:n]
    sd = _std(np.asarray(J)[:n], np.asarray(res.cov))
    moving = np.abs(v) > MOVING * float(vmax)
    return Band(t=t, value=np.where(moving, s, np.nan), std=np.where(moving, sd, np.nan))

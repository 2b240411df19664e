"""The campaign model of MODEL.md §4: one slip law shared by every recording of a track.

Data: each recording r gives, from its own fit, the steady slip s_r and the local slope
b_r = ds/da at the steady state (per mm/s^2), with their 2x2 covariance, and it knows its
mass m_r, drawbar pull F_d,r and ground g_r. The joint model predicts

    F_r   = m_r C_rr[g_r] g + F_d,r                       steady traction, N
    s_r   = s(F_r)                                        the law's steady slip
    b_r   = s'(F_r) m_r / 1000                            dF/da = m / 1000

    linear:          s(F) = 2 F / (k n L)
    janosi_hanamoto: s(F) = -s_K ln(1 - F u),  u = 1 / F_max[g],  s_K = 2 / (k n L u)

so the slope of each recording fixes k (through m) and its steady slip fixes C_rr of its
ground (through F_d and m); at several pulls the curvature of s(F) names the sliding law.
The sliding law is named when it earns its parameters by the explanation's criterion
(BIC lower by more than 10). A recording whose point disagrees with the shared law
(chi-square of its two numbers against the prediction, p below 0.01 / N) is flagged and
left out, one at a time, worst first, and the law is refitted without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from ..model._physics import G

DELTA_BIC_NAMED = -10.0  # the explanation's criterion (README "Finding what the model left out")
FLAG_ALPHA = 0.01  # a recording is flagged when its p-value < FLAG_ALPHA / N
Z95 = 1.959963984540054


@dataclass
class Point:
    """One recording's contribution to the campaign (from its own fit)."""

    name: str
    slip: float  # steady slip s0 under the recording's final model
    slope: float  # ds/da at the steady state, per mm/s^2
    cov: np.ndarray  # (2, 2) covariance of (slip, slope)
    mass_kg: float
    drawbar_pull_N: float
    ground: str
    n: int
    L: float

    def __post_init__(self):
        self.cov = np.asarray(self.cov, float).reshape(2, 2)

    @property
    def own_traction(self) -> tuple[float, float]:
        """F0 = m C_rr g + F_d from this recording alone, m s / (1000 b), with its std
        (exact under the linear law; under a sliding law it reads s / s' instead of F)."""
        F = self.mass_kg * self.slip / (1000.0 * self.slope)
        g = np.array([F / self.slip, -F / self.slope])
        return float(F), float(np.sqrt(max(g @ self.cov @ g, 0.0)))

    @classmethod
    def from_dict(cls, d: dict) -> "Point":
        return cls(name=d["name"], slip=float(d["slip"]), slope=float(d["slope"]),
                   cov=np.asarray(d["cov"], float), mass_kg=float(d["mass_kg"]),
                   drawbar_pull_N=float(d.get("drawbar_pull_N") or 0.0),
                   ground=str(d.get("ground") or "default"), n=int(d["n"]), L=float(d["L"]))

    def as_dict(self) -> dict:
        return {"name": self.name, "slip": self.slip, "slope": self.slope,
                "cov": self.cov.tolist(), "mass_kg": self.mass_kg,
                "drawbar_pull_N": self.drawbar_pull_N, "ground": self.ground,
                "n": self.n, "L": self.L}


def _log_ratio(z):
    """-ln(1 - z) / z, 1 at z = 0."""
    z = np.asarray(z, float)
    small = np.abs(z) < 1e-6
    zs = np.where(small, 0.5, z)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(small, 1.0 + z / 2, -np.log1p(-zs) / zs)


class _Design:
    """Index bookkeeping of the parameter vector [k, C_rr per ground, (u per ground)]."""

    def __init__(self, points, law):
        self.law = law
        self.grounds = sorted({p.ground for p in points})
        self.gi = np.array([self.grounds.index(p.ground) for p in points])
        self.m = np.array([p.mass_kg for p in points])
        self.Fd = np.array([p.drawbar_pull_N for p in points])
        self.nL = float(points[0].n * points[0].L)
        self.y = np.array([[p.slip, p.slope] for p in points])
        self.W = np.array([np.linalg.cholesky(np.linalg.inv(p.cov)).T for p in points])
        ng = len(self.grounds)
        self.names = ["k"] + [f"C_rr[{g}]" for g in self.grounds]
        if law == "janosi_hanamoto":
            self.names += [f"inv_F_max[{g}]" for g in self.grounds]
        self.ng = ng

    @property
    def dim(self):
        return len(self.names)

    def split(self, th):
        th = np.atleast_2d(th)
        k = th[:, 0:1]
        c = th[:, 1:1 + self.ng][:, self.gi]
        u = (th[:, 1 + self.ng:1 + 2 * self.ng][:, self.gi] if self.law == "janosi_hanamoto"
             else np.zeros_like(c))
        return k, c, u

    def predict(self, th):
        """(M, N, 2) predicted (slip, slope); traction (M, N)."""
        k, c, u = self.split(th)
        F = self.m * c * G + self.Fd
        a = 2.0 / (k * self.nL)
        z = u * F
        s = a * F * _log_ratio(z)
        b = a / (1.0 - z) * self.m / 1000.0
        return np.stack([s, b], axis=-1), F

    def whitened(self, th):
        pred, F = self.predict(th)
        r = self.y[None] - pred  # (M, N, 2)
        return np.einsum("nij,mnj->mni", self.W, r), F

    def valid(self, th):
        k, c, u = self.split(th)
        F = self.m * c * G + self.Fd
        return (k[:, 0] > 0) & np.all(u >= 0, axis=1) & np.all(u * F < 1 - 1e-9, axis=1)


@dataclass
class LawFit:
    """Least-squares fit of one law to the campaign points."""

    law: str
    names: list
    theta: np.ndarray
    cov: np.ndarray
    chi2: float
    n_data: int
    chi2_each: np.ndarray  # per recording (2 numbers each)
    traction: np.ndarray  # per recording, N
    design: object = field(repr=False, default=None)

    @property
    def n_params(self) -> int:
        return len(self.theta)

    @property
    def bic(self) -> float:
        return self.chi2 + self.n_params * math.log(self.n_data)

    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))


def _start(design: _Design, points) -> np.ndarray:
    # k from the slopes (mass-weighted), C_rr per ground from the slips at that k
    k_each = np.array([2 * p.mass_kg / (1000.0 * p.slope * design.nL) for p in points])
    k0 = float(np.median(k_each[np.isfinite(k_each) & (k_each > 0)])) if np.any(k_each > 0) \
        else 0.3
    th = [k0]
    for g in design.grounds:
        cs = [(p.slip * k0 * design.nL / 2 - p.drawbar_pull_N) / (p.mass_kg * G)
              for p in points if p.ground == g]
        th.append(float(np.median(cs)))
    if design.law == "janosi_hanamoto":
        th += [0.0] * design.ng
    return np.array(th, float)


def fit_law(points, law: str = "linear", start=None) -> LawFit:
    """Weighted least squares of one law (Gauss-Newton covariance)."""
    d = _Design(points, law)
    th0 = _start(d, points) if start is None else np.asarray(start, float)
    lo = np.full(d.dim, -np.inf)
    lo[0] = 1e-9
    if law == "janosi_hanamoto":
        lo[1 + d.ng:] = 0.0

    def res(th):
        r, _ = d.whitened(th)
        return r[0].ravel()

    starts = [th0]
    if law == "janosi_hanamoto" and start is None:
        Fmax_obs = max(np.max(d.m * th0[1:1 + d.ng][d.gi] * G + d.Fd), 1e-6)
        for frac in (0.1, 0.4, 0.7):
            t = th0.copy()
            t[1 + d.ng:] = frac / Fmax_obs
            starts.append(t)
    best = None
    for s in starts:
        s = np.maximum(s, lo + 1e-12)
        if not d.valid(s)[0]:
            continue
        try:
            sol = optimize.least_squares(res, s, bounds=(lo, np.inf), method="trf",
                                         x_scale="jac", xtol=1e-11, ftol=1e-11, gtol=1e-11,
                                         max_nfev=500)
        except ValueError:
            continue
        if not np.all(np.isfinite(sol.fun)) or not d.valid(sol.x)[0]:
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        raise ValueError(f"the {law} law could not be fitted to the campaign points")
    J = best.jac
    cov = np.linalg.pinv(J.T @ J)
    r, F = d.whitened(best.x)
    chi2_each = np.sum(r[0] ** 2, axis=1)
    return LawFit(law=law, names=list(d.names), theta=best.x, cov=cov,
                  chi2=float(np.sum(chi2_each)), n_data=2 * len(points), chi2_each=chi2_each,
                  traction=F[0], design=d)


def fit_with_flags(points, law: str, alpha: float = FLAG_ALPHA):
    """Fit, then flag and drop the worst recording while its leave-one-out p < alpha / N
    (its point against the law fitted to the other kept recordings); returns (fit on the
    kept points, kept mask, p-value of every point: leave-one-out for the kept ones,
    against the final law for the flagged ones)."""
    keep = np.ones(len(points), bool)
    N = len(points)
    while True:
        kept_idx = np.flatnonzero(keep)
        f = fit_law([points[i] for i in kept_idx], law)
        c_all = point_chi2(f, points)
        c_loo = c_all.copy()
        for i in kept_idx:
            others = [points[j] for j in kept_idx if j != i]
            if len(others) < 2 or points[i].ground not in {q.ground for q in others}:
                continue  # the only recording of its ground: tested in-sample
            try:
                fi = fit_law(others, law, start=f.theta)
            except ValueError:
                continue
            c_loo[i] = point_chi2(fi, [points[i]])[0]
        grounds_kept = [points[j].ground for j in kept_idx]
        alone = np.array([grounds_kept.count(p.ground) <= 1 for p in points])
        # the last recording of a ground is not flagged: its C_rr would be its own
        c_kept = np.where(keep & ~alone, c_loo, -np.inf)
        worst = int(np.argmax(c_kept))  # chi-square, not p: p underflows to 0
        if stats.chi2.sf(c_kept[worst], 2) < alpha / N and keep.sum() > 2:
            keep[worst] = False
            continue
        return f, keep, stats.chi2.sf(np.where(keep, c_loo, c_all), 2)


def point_pvalues(f: LawFit, points) -> np.ndarray:
    """p-value of every point (kept or not) against the law `f` (see `point_chi2`)."""
    return stats.chi2.sf(point_chi2(f, points), 2)


def point_chi2(f: LawFit, points) -> np.ndarray:
    """Chi-square (2 dof) of every point's (slip, slope) against the law `f`'s
    prediction, with the law's own uncertainty added to the point's covariance."""
    d = _Design(points, f.law)
    # the fitted law's parameters mapped onto these points' grounds
    th = _remap(f, d)
    out = np.empty(len(points))
    pred, _ = d.predict(th)
    J = _jac(lambda t: d.predict(t)[0][0].ravel(), th)
    C = J @ _remap_cov(f, d) @ J.T
    for i, p in enumerate(points):
        r = d.y[i] - pred[0, i]
        S = p.cov + C[2 * i:2 * i + 2, 2 * i:2 * i + 2]
        out[i] = float(r @ np.linalg.solve(S, r))
    return out


def _remap(f: LawFit, d: _Design) -> np.ndarray:
    idx = _remap_index(f, d)
    return np.array([f.theta[i] if i >= 0 else 0.0 for i in idx])


def _remap_cov(f: LawFit, d: _Design) -> np.ndarray:
    idx = _remap_index(f, d)
    C = np.zeros((len(idx), len(idx)))
    for a, i in enumerate(idx):
        for b, j in enumerate(idx):
            if i >= 0 and j >= 0:
                C[a, b] = f.cov[i, j]
    return C


def _remap_index(f: LawFit, d: _Design):
    out = []
    for name in d.names:
        if name in f.names:
            out.append(f.names.index(name))
        elif name.startswith("C_rr["):
            raise ValueError(f"no recording left on ground {name[5:-1]!r} to fit its C_rr")
        else:
            out.append(-1)
    return out


def _jac(fun, th, rel=1e-6):
    f0 = np.asarray(fun(th))
    J = np.empty((f0.size, th.size))
    for j in range(th.size):
        h = rel * max(abs(th[j]), 1e-6)
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        J[:, j] = (np.asarray(fun(tp)) - np.asarray(fun(tm))) / (tp[j] - tm[j])
    return J


# -- posterior --------------------------------------------------------------------------

def sample_law(f: LawFit, *, seed: int = 0, walkers: int = 32, time_budget_s: float = 600.0,
               target_ess: float = 2000.0, max_steps: int = 30000):
    """emcee posterior of the law's parameters (flat priors: k > 0, 1/F_max >= 0,
    F < F_max at every kept recording); a Chain (fitlug.posterior._mcmc).

    Stops on convergence (ESS >= target_ess, chain >= 50 autocorrelation times) or at
    max_steps: the same seed gives the same numbers on any machine; the time budget is
    only a safety net."""
    from ..posterior._mcmc import run_ensemble

    d = f.design

    def log_prob(th):
        th = np.atleast_2d(th)
        out = np.full(len(th), -np.inf)
        ok = d.valid(th)
        if np.any(ok):
            r, _ = d.whitened(th[ok])
            out[ok] = -0.5 * np.sum(r ** 2, axis=(1, 2))
        return out

    rng = np.random.default_rng(seed)
    sd = f.std()
    sd = np.where(sd > 0, sd, 1e-6 * np.maximum(np.abs(f.theta), 1e-6))
    p0 = []
    while len(p0) < walkers:
        cand = f.theta + 0.1 * sd * rng.standard_normal((walkers, d.dim))
        if d.law == "janosi_hanamoto":
            ui = slice(1 + d.ng, 1 + 2 * d.ng)
            cand[:, ui] = np.abs(cand[:, ui])
        ok = np.isfinite(log_prob(cand))
        p0.extend(cand[ok])
    p0 = np.array(p0[:walkers])
    return run_ensemble(log_prob, p0, names=d.names, seed=int(rng.integers(2 ** 31)),
                        time_budget_s=time_budget_s, target_ess=target_ess,
                        max_steps=max_steps)


def curve(law: str, theta_samples: np.ndarray, names, ground: str, F: np.ndarray, nL: float):
    """Slip of the law on ground `ground` at tractions F for each parameter sample:
    (M, len(F)). The linear law does not depend on the ground."""
    th = np.atleast_2d(theta_samples)
    k = th[:, [names.index("k")]]
    a = 2.0 / (k * nL)
    if law == "janosi_hanamoto":
        u = th[:, [names.index(f"inv_F_max[{ground}]")]]
        z = np.clip(u * F[None], None, 1 - 1e-12)
        return a * F[None] * _log_ratio(z)
    return a * F[None] * np.ones((len(th), 1))

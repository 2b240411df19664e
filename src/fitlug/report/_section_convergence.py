"""The report's "Convergence diagnostics" section and its plots: the sampler's settings and
status, ArviZ's per-parameter diagnostics from posterior.nc and the walker traces."""

from __future__ import annotations

import os

import numpy as np

from . import _format as F
from ._figure import FIG_W, _ax, _fig, _locator, figure_html, new_figure
from ._markup import _e, _table


def _arviz_diagnostics(out_dir):
    """(names, rows, chains) from DIR/posterior.nc: R-hat, bulk/tail ESS, MCSE per
    parameter, and the draws (walker, draw) of each sampled parameter; None without it."""
    path = os.path.join(out_dir, "posterior.nc")
    if not os.path.isfile(path):
        return None
    import logging
    import warnings

    log = logging.getLogger("arviz")
    level = log.level
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log.setLevel(logging.ERROR)  # a short chain is reported in the table, not on stderr
        try:
            import arviz as az

            idata = az.from_netcdf(path)
            summ = az.summary(idata, kind="diagnostics", round_to="none")
            post = idata.posterior
            chains = {k: np.asarray(post[k].values) for k in post.data_vars}
        except Exception:  # noqa: BLE001 - an unreadable file only loses this table
            return None
        finally:
            log.setLevel(level)
    return summ, chains


def _convergence(st, fj, out_dir) -> str:
    mc = fj.get("mcmc")
    if not mc:
        return "<p>Least squares only: no chain was run.</p>"
    ok = mc.get("converged")
    status = ('<span class="ok">converged</span>' if ok
              else '<span class="bad">not converged</span>')
    rows = [["status", status], ["message", _e(mc.get("message", ""))],
            ["method", _e(mc.get("method", ""))],
            ["marginalised", _e(mc.get("marginalised", ""))],
            ["walkers", F.num(mc.get("walkers"))],
            ["steps (burn-in)", f'{F.num(mc.get("steps"))} ({F.num(mc.get("burn_in"))})'],
            ["acceptance fraction", F.sig(mc.get("acceptance"), 3)],
            ["wall time", F.sig(mc.get("seconds"), 2) + " s"], ["seed", F.num(mc.get("seed"))]]
    chk = mc.get("linearity_check") or {}
    if chk:
        rows.append(["linearisation check",
                     f'max |Δχ²| = {F.sig(chk.get("max_delta_chi2"), 2)} at '
                     f'{F.num(chk.get("points"))} points {F.num(chk.get("sigma"))} σ out '
                     f'(tolerance {F.num(chk.get("tolerance"))})'])
    pri = mc.get("priors") or {}
    rows.append(["priors", _e("; ".join(f"{k}: {v}" for k, v in pri.items()))])
    out = _table(["diagnostic", "value"], rows)
    diag = _arviz_diagnostics(out_dir)
    tau = mc.get("autocorr_time_per_parameter") or {}
    sampled = list(mc.get("parameters") or tau)
    if diag is not None:
        summ, chains = diag
        prow = []
        for name in summ.index:
            r = summ.loc[name]
            mean = float(np.mean(chains[name])) if name in chains else None
            prow.append([_e(name) + (" (sampled)" if name in sampled else ""),
                         F.sig(mean, 6), F.sig(r.get("mcse_mean"), 2),
                         F.sig(r.get("r_hat"), 4), F.sig(r.get("ess_bulk"), 3),
                         F.sig(r.get("ess_tail"), 3),
                         F.sig(tau.get(name), 3) if name in tau else ""])
        out += ("<p>Per parameter, computed by ArviZ from the saved samples "
                "(<code>posterior.nc</code>; the walkers are treated as chains, which "
                "slightly overstates R-hat's power for an ensemble sampler):</p>"
                + _table(["parameter", "mean", "MCSE of mean", "R-hat", "ESS bulk",
                          "ESS tail", "τ (steps)"], prow))
        traces = {k: chains[k] for k in sampled if k in chains} or {
            k: v for k, v in list(chains.items())[:4]}
        fig = plot_traces(traces)
        out += figure_html(fig, "walker traces of every sampled parameter",
                           "Walker traces (after burn-in) of every sampled parameter: each "
                           "line is one walker. Look for a stationary band without trends "
                           "or stuck walkers.")
    elif "post_chain" in st:
        fig, ax = _fig(FIG_W, 2.6)
        name = (st["meta"].get("post_parameters") or ["s0"])[0]
        plot_trace(st["post_chain"], ax=ax[0, 0], name=name)
        out += figure_html(fig, "walker traces of the slip",
                           f"Walker traces of {_e(name)} after burn-in (posterior.nc not "
                           "found: the other parameters' traces need it).")
    return out


def plot_trace(chain, ax=None, name: str = "s0"):
    """Walker traces of one sampled parameter (draws after burn-in)."""
    ax = _ax(ax, (6, 2.5))
    chain = np.asarray(chain)
    ax.plot(chain, lw=0.3, alpha=0.6)
    ax.set_xlabel("step after burn-in")
    ax.set_ylabel(name)
    ax.ticklabel_format(axis="y", useOffset=False)
    return ax


def plot_traces(chains: dict):
    """Walker traces, one panel per parameter: chains {name: (walkers, draws)}."""
    k = max(len(chains), 1)
    fig, axes = new_figure(9.0, 0.4 + 1.6 * k, k, 1, sharex=True)
    for ax, (name, c) in zip(axes[:, 0], chains.items()):
        c = np.asarray(c)
        ax.plot(c.T, lw=0.3, alpha=0.5)
        ax.set_ylabel(name)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.yaxis.set_major_locator(_locator(4))
    axes[-1, 0].set_xlabel("draw after burn-in")
    return fig

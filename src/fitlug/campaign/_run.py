"""`fitlug.campaign`: fit every recording (on Dask workers), then the shared slip law.

Sources are CSV files (their rig.toml beside them), folders (every CSV under them) and
glob patterns, or `Recording` objects (with their `Rig`). Each recording is fitted in full
by `fit_recording` into OUT/<name>/; the campaign model (`_model`) is fitted to the
recordings' points; campaign.json and campaign.html are written into OUT.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import logging
import math
import os
import sys
from dataclasses import dataclass, field

import numpy as np

from .._errors import FitError, InputError
from .._version import __version__
from . import _model
from ._job import fit_recording

Z95 = 1.959963984540054


@dataclass
class Source:
    """One recording to fit: a CSV path (and its rig), or a Recording object."""

    name: str
    csv: str | None
    rig: object
    recording: object = None


@dataclass
class RecordingOutcome:
    """What the campaign concluded about one recording."""

    name: str
    input: str | None
    out: str
    status: str  # fitted | unchanged | failed
    error: str | None = None
    point: dict | None = None
    ground: str | None = None
    mass_kg: float | None = None
    drawbar_pull_N: float | None = None
    traction: tuple | None = None  # (value, std) on the campaign's C_rr
    traction_own: tuple | None = None  # (value, std) from the recording alone
    p_value: float | None = None
    consistent: bool | None = None
    reason: str | None = None
    seconds: float = 0.0


@dataclass
class CampaignResult:
    """The campaign's answer (see DATA.md campaign.json and `to_json`)."""

    law: str
    delta_bic: float
    fits: dict  # law id -> _model.LawFit (least squares, on the kept recordings)
    names: list  # parameter names of the chosen law
    samples: np.ndarray  # posterior samples (M, dim) of the chosen law
    mcmc: dict
    recordings: list  # RecordingOutcome, in source order
    estimates: dict  # name -> {"value", "std", "ci95"}
    curves: dict  # ground (or "all") -> {"traction_N", "slip", "slip_lo95", "slip_hi95"}
    alpha: float
    out: str | None = None
    nL: float = 0.0
    settings: dict = field(default_factory=dict)

    @property
    def stiffness(self) -> dict:
        return self.estimates["k"]

    @property
    def rolling_resistance(self) -> dict:
        return {n[5:-1]: e for n, e in self.estimates.items() if n.startswith("C_rr[")}

    @property
    def F_max(self) -> dict | None:
        if self.law != "janosi_hanamoto":
            return None
        return {n[6:-1]: e for n, e in self.estimates.items() if n.startswith("F_max[")}

    @property
    def flagged(self) -> list:
        return [r for r in self.recordings if r.consistent is False]

    @property
    def failed(self) -> list:
        return [r for r in self.recordings if r.status == "failed"]

    def to_json(self, out_dir: str | None = None) -> dict:
        out_dir = out_dir or self.out or "."
        recs = []
        for r in self.recordings:
            fit_rel = (os.path.relpath(os.path.join(r.out, "fit.json"), out_dir)
                       if r.status != "failed" else None)
            rep = os.path.join(r.out, "report.html")
            e = {"name": r.name, "input": r.input, "fit": fit_rel,
                 "report": (os.path.relpath(rep, out_dir) if os.path.isfile(rep) else None),
                 "status": r.status, "ground": r.ground, "mass_kg": r.mass_kg,
                 "pull": r.drawbar_pull_N,
                 "traction_N": _vs(r.traction), "traction_own_N": _vs(r.traction_own),
                 "slip": None, "slope_per_mm_s2": None,
                 "consistent": r.consistent, "p_value": _num(r.p_value),
                 "flag_reason": r.reason, "error": r.error}
            if r.point:
                cov = np.asarray(r.point["cov"])
                e["slip"] = {"value": r.point["slip"], "std": _num(math.sqrt(max(cov[0, 0], 0)))}
                e["slope_per_mm_s2"] = {"value": r.point["slope"],
                                        "std": _num(math.sqrt(max(cov[1, 1], 0)))}
                e["effects"] = r.point.get("effects")
                e["verdict"] = r.point.get("verdict")
            recs.append(e)
        fl, fj = self.fits.get("linear"), self.fits.get("janosi_hanamoto")
        chosen = self.fits[self.law]
        law_params = {"k_N_per_mm": self.estimates["k"]["value"]}
        law_std = {"k_N_per_mm": self.estimates["k"]["std"]}
        if self.law == "janosi_hanamoto":
            for g, e in self.F_max.items():
                law_params[f"F_max_N[{g}]"] = e["value"]
                law_std[f"F_max_N[{g}]"] = e["std"]
        main = "all" if "all" in self.curves else max(
            self.curves, key=lambda g: sum(r.ground == g for r in self.recordings))
        return {
            "fitlug_version": __version__,
            "recordings": recs,
            "law": {"id": self.law, "delta_bic": _num(self.delta_bic),
                    "criterion": "janosi_hanamoto named when its BIC is lower than the "
                                 "linear law's by more than 10 (delta_bic < -10)",
                    "params": law_params, "params_std": law_std,
                    "compared": {name: {"chi2": _num(f.chi2), "n_params": f.n_params,
                                        "n_data": f.n_data, "bic": _num(f.bic),
                                        "params": dict(zip(f.names, map(_num, f.theta))),
                                        "params_std": dict(zip(f.names, map(_num, f.std())))}
                                 for name, f in (("linear", fl), ("janosi_hanamoto", fj))
                                 if f is not None}},
            "stiffness_N_per_mm": self.estimates["k"],
            "rolling_resistance": self.rolling_resistance,
            "F_max_N": self.F_max,
            "curve": self.curves[main],
            "curves": self.curves,
            "consistency": {"test": "chi-square (2 dof) of each recording's (slip, ds/da) "
                                    "against the shared law, the law's uncertainty added",
                            "alpha": self.alpha, "threshold": self.alpha / max(
                                len([r for r in self.recordings if r.point]), 1),
                            "flagged": [r.name for r in self.flagged]},
            "failed": [{"name": r.name, "error": r.error} for r in self.failed],
            "mcmc": self.mcmc,
            "uncertainty_method": "posterior (emcee) of the campaign model; each recording's "
                                  "point from its least-squares fit (delta method)",
            "n_contact": int(self.settings.get("n", 0)) or None,
            "load_bearing_length_mm": self.settings.get("L"),
            "settings": {k: v for k, v in self.settings.items() if k not in ("n", "L")},
        }


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _vs(t):
    return None if t is None else {"value": _num(t[0]), "std": _num(t[1])}


# -- sources ----------------------------------------------------------------------------

def _rig_beside(csv: str) -> str | None:
    folder = os.path.dirname(os.path.abspath(csv))
    stem = os.path.splitext(os.path.basename(csv))[0]
    for name in (f"{stem}.rig.toml", "rig.toml"):
        p = os.path.join(folder, name)
        if os.path.isfile(p):
            return p
    return None


def _csvs_in(folder: str) -> list[str]:
    out = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        out += [os.path.join(root, f) for f in sorted(files)
                if f.lower().endswith(".csv") and not f.startswith(".")]
    return out


def _name(csv: str, root: str | None) -> str:
    stem = os.path.splitext(os.path.basename(csv))[0]
    parent = os.path.basename(os.path.dirname(os.path.abspath(csv)))
    return parent if stem == "trajectories" and parent else stem


def resolve_sources(sources) -> list[Source]:
    """Expand paths, folders and globs (and Recording objects) into checked sources.

    Raises:
        InputError: a path that does not exist, a folder or pattern without a CSV, a
            recording without rig.toml or without mass, mixed n or L (one line each).
    """
    from ..io import Recording, Rig, read_rig

    if isinstance(sources, (str, os.PathLike)) or isinstance(sources, Recording):
        sources = [sources]
    items: list[Source] = []
    for src in sources:
        if isinstance(src, tuple) and len(src) == 2 and isinstance(src[0], Recording):
            rec, rig = src
            items.append(Source(name=_rec_name(rec, len(items)), csv=rec.path, rig=rig,
                                recording=rec))
            continue
        if isinstance(src, Recording):
            if src.path and _rig_beside(src.path):
                rig = read_rig(_rig_beside(src.path))
            else:
                raise InputError(src.path or f"recording {len(items) + 1}",
                                 "a Recording without its rig: pass (recording, rig)")
            items.append(Source(name=_rec_name(src, len(items)), csv=src.path, rig=rig,
                                recording=src))
            continue
        path = os.fspath(src)
        if any(c in path for c in "*?["):
            matches = sorted(glob.glob(path, recursive=True))
            csvs = [c for m in matches for c in (_csvs_in(m) if os.path.isdir(m) else [m])
                    if c.lower().endswith(".csv")]
            if not csvs:
                raise InputError(path, "the pattern matches no trajectories CSV")
        elif os.path.isdir(path):
            csvs = _csvs_in(path)
            if not csvs:
                raise InputError(path, "no trajectories CSV in this folder (nor below it)")
        elif os.path.isfile(path):
            csvs = [path]
        else:
            raise InputError(path, "no such file or folder")
        for csv in csvs:
            rig_path = _rig_beside(csv)
            if rig_path is None:
                raise InputError(csv, "no rig.toml beside it: a campaign needs each "
                                      "recording's rig (mass, drawbar pull, ground)")
            items.append(Source(name=_name(csv, path), csv=csv, rig=read_rig(rig_path)))
    if not items:
        raise InputError(None, "no recordings given")
    _check(items)
    return items


def _rec_name(rec, i: int) -> str:
    if rec.path:
        return _name(rec.path, None)
    return f"recording_{i + 1:02d}"


def _check(items: list[Source]) -> None:
    first = items[0]
    seen: dict[str, int] = {}
    for s in items:
        where = getattr(s.rig, "path", None) or s.csv or s.name
        if s.rig.mass_kg is None:
            raise InputError(where, "[vehicle] mass_kg is missing: a campaign needs every "
                                    "recording's mass (its traction m C_rr g + F_d)")
        for attr, key in (("lugs_in_contact", "[track] lugs_in_contact"),
                          ("load_bearing_length_mm", "[track] load_bearing_length_mm")):
            a, b = getattr(s.rig, attr), getattr(first.rig, attr)
            if a != b:
                raise InputError(where, f"{key} = {a:g} differs from {b:g} of {first.name}: a "
                                        "campaign is one track (same n and L)")
        # unique output folder names
        if s.name in seen:
            seen[s.name] += 1
            s.name = f"{s.name}_{seen[s.name]}"
        else:
            seen[s.name] = 1


# -- running ----------------------------------------------------------------------------

def _recording_hash(rec) -> str:
    h = hashlib.sha256()
    for a in (rec.t, rec.marker_index, rec.x, rec.y):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((rec.markers, rec.roles)).encode())
    return h.hexdigest()


def _jobs(items, out, options):
    jobs = []
    for s in items:
        kw = dict(options)
        kw.update(out_dir=os.path.join(out, s.name), name=s.name, rig=s.rig)
        if s.recording is not None and s.csv is None:
            kw["recording"] = s.recording
        jobs.append((s.csv if s.csv is not None else f"<{s.name}>", kw))
    return jobs


def _worker_job(csv, kw):
    """What a worker runs (module-level so it pickles by reference)."""
    return fit_recording(csv, **kw)


def _run_local(jobs, progress):
    from tqdm.auto import tqdm

    out = []
    with tqdm(total=len(jobs), desc="recordings", unit="rec", disable=not progress,
              file=sys.stderr) as bar:
        for csv, kw in jobs:
            out.append(_worker_job(csv, kw))
            bar.update(1)
    return out


def _run_dask(jobs, *, scheduler, workers, progress):
    import dask
    from dask.distributed import Client, LocalCluster, as_completed
    from tqdm.auto import tqdm

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InputError(scheduler, f"cannot reach the Dask scheduler: {exc}") from None
    else:
        # workers are started clean (spawn), never forked from a process with JAX loaded
        dask.config.set({"distributed.worker.multiprocessing-method": "spawn"})
        cluster = LocalCluster(n_workers=max(int(workers), 1), threads_per_worker=1,
                               processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    try:
        futures = {}
        for i, (csv, kw) in enumerate(jobs):
            f = client.submit(_worker_job, csv, kw, key=f"fitlug-{kw['name']}-{i}", pure=False)
            futures[f] = i
        results = [None] * len(jobs)
        with tqdm(total=len(jobs), desc="recordings", unit="rec", disable=not progress,
                  file=sys.stderr) as bar:
            for f in as_completed(futures):
                i = futures[f]
                try:
                    results[i] = f.result()
                except Exception as exc:  # noqa: BLE001  (a worker lost, a pickling error)
                    csv, kw = jobs[i]
                    results[i] = {"name": kw["name"], "input": csv, "out": kw["out_dir"],
                                  "status": "failed", "point": None, "seconds": 0.0,
                                  "error": f"{csv}: {type(exc).__name__}: "
                                           f"{(str(exc).splitlines() or [''])[0]}"}
                bar.update(1)
        return results
    finally:
        # the results are in hand: a slow worker shutdown must not lose them
        with contextlib.suppress(Exception):
            client.close(timeout=30)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=30)


def campaign(recordings, *, out: str | None = None, scheduler: str | None = None,
             workers: int = 1, seed: int = 0, explain: bool = True, mcmc: bool = True,
             report: bool = True, resume: bool = True, mcmc_budget: float = 60.0,
             progress: bool = False, write: bool = True, alpha: float = _model.FLAG_ALPHA,
             campaign_budget_s: float = 600.0) -> CampaignResult:
    """Fit a campaign: every recording in full, then the track's shared slip law.

    Args:
        recordings: CSV paths (rig.toml beside each), folders, glob patterns, Recording
            objects (read from a file with its rig beside it) or (Recording, Rig) pairs.
        out: output folder (OUT/<recording>/ per recording, OUT/campaign.json and .html);
            default fits/campaign.
        scheduler: address of a running Dask scheduler (tcp://host:8786); None: a
            LocalCluster of `workers` processes, or workers=0: in this process, no Dask.
        seed: seed of every random step (per-recording posteriors, campaign posterior).
        explain, mcmc, report: per-recording stages (as fit-lug's --no-explain ...).
        resume: skip recordings whose inputs, fitlug version and options are unchanged.
    Returns:
        CampaignResult. Raises InputError for bad sources (one line), FitError when
        fewer than two recordings could be fitted.
    """
    items = resolve_sources(recordings)
    out = out or os.path.join("fits", "campaign")
    options = {"seed": seed, "explain": explain, "mcmc": mcmc, "report": report,
               "mcmc_budget": mcmc_budget, "resume": resume}
    jobs = _jobs(items, out, options)
    if scheduler is None and workers == 0:
        raw = _run_local(jobs, progress)
    else:
        raw = _run_dask(jobs, scheduler=scheduler, workers=workers, progress=progress)
    outcomes = [RecordingOutcome(name=r["name"], input=r["input"], out=r["out"],
                                 status=r["status"], error=r.get("error"), point=r.get("point"),
                                 ground=s.rig.ground or "default", mass_kg=s.rig.mass_kg,
                                 drawbar_pull_N=s.rig.drawbar_pull_N,
                                 seconds=float(r.get("seconds") or 0.0))
                for r, s in zip(raw, items)]
    result = fit_points(outcomes, seed=seed, alpha=alpha, budget_s=campaign_budget_s)
    result.out = out
    result.settings.update({"seed": seed, "explain": explain, "mcmc": mcmc,
                            "scheduler": scheduler, "workers": workers})
    if write:
        write_campaign(result, out)
    return result


def fit_points(outcomes, *, seed: int = 0, alpha: float = _model.FLAG_ALPHA,
               budget_s: float = 600.0) -> CampaignResult:
    """The campaign model on recordings whose points are known (outcomes with `point`
    dicts, or plain point dicts): law choice, flags, posterior, curves."""
    outs = []
    for o in outcomes:
        if isinstance(o, dict):
            o = RecordingOutcome(name=o["name"], input=None, out=o["name"], status="fitted",
                                 point=o, ground=o.get("ground") or "default",
                                 mass_kg=o["mass_kg"], drawbar_pull_N=o.get("drawbar_pull_N"))
        outs.append(o)
    ok = [o for o in outs if o.point is not None]
    if len(ok) < 2:
        errs = "; ".join(o.error or o.name for o in outs if o.point is None)[:300]
        raise FitError(f"a campaign needs at least two fitted recordings, got {len(ok)}"
                       + (f" ({errs})" if errs else ""))
    for o in ok:
        o.point = dict(o.point, ground=o.ground or o.point.get("ground") or "default")
    points = [_model.Point.from_dict(o.point) for o in ok]
    law, fit, keep, pvals, fits, dbic = choose_law(points, alpha)
    chain = _model.sample_law(fit, seed=seed, time_budget_s=budget_s)
    samples = chain.flat() if hasattr(chain, "flat") else chain.samples.reshape(-1, fit.n_params)
    names = list(fit.names)
    est = {}
    for i, nm in enumerate(names):
        est[nm] = _estimate(samples[:, i])
    if law == "janosi_hanamoto":
        for i, nm in enumerate(names):
            if nm.startswith("inv_F_max["):
                g = nm[10:-1]
                u = samples[:, i]
                with np.errstate(divide="ignore"):
                    F = np.where(u > 0, 1.0 / np.maximum(u, 1e-300), np.inf)
                est[f"F_max[{g}]"] = _estimate(F)
    d = fit.design
    for o, p_ok, p in zip(ok, keep, pvals):
        o.p_value = float(p)
        o.consistent = bool(p_ok)
        o.traction_own = _model.Point.from_dict(o.point).own_traction
        g = o.ground
        cname = f"C_rr[{g}]"
        if cname in names:
            c = samples[:, names.index(cname)]
            F = o.mass_kg * c * _model.G + (o.drawbar_pull_N or 0.0)
            o.traction = (float(np.median(F)), float(np.std(F, ddof=1)))
        else:
            o.traction = o.traction_own
        if not p_ok:
            o.reason = _flag_reason(o, fit, samples, names, d, alpha, len(ok))
    curves = _curves(law, samples, names, ok, keep, d.nL)
    mc = {"walkers": int(chain.samples.shape[1]), "steps": int(chain.steps),
          "discard": int(chain.discard), "autocorr_time": _num(np.max(chain.tau)),
          "ess": _num(np.min(chain.ess)), "converged": bool(chain.converged),
          "reason": chain.reason or None, "seed": seed}
    n, L = points[0].n, points[0].L
    return CampaignResult(law=law, delta_bic=dbic, fits=fits, names=names, samples=samples,
                          mcmc=mc, recordings=outs, estimates=est, curves=curves, alpha=alpha,
                          nL=d.nL, settings={"n": n, "L": L})


def choose_law(points, alpha: float = _model.FLAG_ALPHA):
    """Flags under each law; the kept set is that of the law that keeps more recordings
    (a curved law flags many recordings under the linear one; a stray recording is flagged
    under both); then the law by BIC on that set, and its own flags."""
    fl, keep_l, p_l = _model.fit_with_flags(points, "linear", alpha)
    fj, keep_j, p_j = _model.fit_with_flags(points, "janosi_hanamoto", alpha)
    keep = keep_j if keep_j.sum() > keep_l.sum() else keep_l
    kept = [p for p, k in zip(points, keep) if k]
    fl_same = _model.fit_law(kept, "linear")
    fj_same = _model.fit_law(kept, "janosi_hanamoto")
    dbic = fj_same.bic - fl_same.bic
    if dbic < _model.DELTA_BIC_NAMED:
        return "janosi_hanamoto", fj, keep_j, p_j, {"linear": fl_same, "janosi_hanamoto": fj}, \
            dbic
    return "linear", fl, keep_l, p_l, {"linear": fl, "janosi_hanamoto": fj_same}, dbic


def _estimate(x) -> dict:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)] if np.any(np.isfinite(x)) else x
    lo, med, hi = np.percentile(x, [2.5, 50, 97.5])
    return {"value": _num(med), "std": _num(np.std(x, ddof=1)), "ci95": [_num(lo), _num(hi)]}


def _flag_reason(o, fit, samples, names, d, alpha, N) -> str:
    p = o.point
    k_med = float(np.median(samples[:, names.index("k")]))
    k_own = 2.0 * o.mass_kg / (1000.0 * p["slope"] * d.nL)
    own = ""
    c = p.get("chi2_per_dof")
    if p.get("verdict") == "unexplained":
        own = (f"; its own fit is unexplained (chi2/dof {c:.3g} under "
               f"{', '.join(p.get('effects') or []) or 'the base model'}): the misfit left in "
               "that recording may bias its point -- read its report before taking it for "
               "another track")
    elif c is not None and c > 3:
        own = (f"; its own fit is poor (chi2/dof {c:.3g} under "
               f"{', '.join(p.get('effects') or []) or 'the base model'}): a misfit the "
               "explanation left in that recording biases its point")
    return (f"pull {o.drawbar_pull_N:g} N, mass {o.mass_kg:g} kg, ground {o.ground}: its point "
            f"(slip {p['slip']:.4g}, ds/da {p['slope']:.3g} per mm/s^2; read with the linear "
            f"law alone k = {k_own:.3g} N/mm, the campaign's {k_med:.3g}) disagrees with the "
            f"shared law: p = {o.p_value:.2g} < {alpha:g}/{N} -- another track, a wrong rig "
            f"(mass, pull, n, L) or another ground{own}")


def _curves(law, samples, names, ok, keep, nL) -> dict:
    F_hi = max((o.traction[0] for o in ok if o.traction), default=1.0) * 1.15
    grounds = sorted({o.ground for o, k in zip(ok, keep) if k})
    keys = ["all"] if law == "linear" else grounds
    out = {}
    rng = np.random.default_rng(0)
    sub = samples if len(samples) <= 4000 else samples[rng.choice(len(samples), 4000, False)]
    for g in keys:
        top = F_hi
        if law == "janosi_hanamoto":
            Fm = 1.0 / np.median(sub[:, names.index(f"inv_F_max[{g}]")])
            top = min(F_hi, 0.97 * Fm) if np.isfinite(Fm) else F_hi
        F = np.linspace(0.0, top, 60)
        S = _model.curve(law, sub, names, g, F, nL)
        lo, med, hi = np.percentile(S, [2.5, 50, 97.5], axis=0)
        out[g] = {"traction_N": F.tolist(), "slip": med.tolist(), "slip_lo95": lo.tolist(),
                  "slip_hi95": hi.tolist()}
    return out


def write_campaign(result: CampaignResult, out: str) -> tuple[str, str]:
    """campaign.json and campaign.html into `out`, atomically."""
    from ..io import write_json

    os.makedirs(out, exist_ok=True)
    jpath = os.path.join(out, "campaign.json")
    doc = result.to_json(out)
    write_json(jpath, doc)
    from ._html import write_campaign_html

    hpath = write_campaign_html(result, doc, out)
    return jpath, hpath

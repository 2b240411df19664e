"""One recording of a campaign: fitted in full (fit, explain, posterior) as `fit-lug` does.

`fit_recording` is the unit of work a Dask worker runs. It writes DIR/<name>/fit.json
(with `provenance` and the recording's campaign point) and report.html, and returns a
small dict that travels back to the client. A recording whose inputs (content hash of
the CSV and of the rig), fitlug version and options are those of an existing fit.json is
not refitted (resume).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import traceback

import numpy as np

from .._version import __version__


def sha256_file(path) -> str | None:
    if path is None or not os.path.isfile(path):
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def sha256_rig(rig) -> str:
    """Content hash of a rig's values (a Rig object without a file)."""
    from dataclasses import asdict

    d = asdict(rig)
    d.pop("path", None)
    d.pop("assumed", None)  # how the rig came, not what it is
    return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()


def provenance(csv_path, rig, options: dict) -> dict:
    rig_hash = sha256_file(rig.path) if getattr(rig, "path", None) else sha256_rig(rig)
    opts = ", ".join(f"{k}={v}" for k, v in sorted(options.items()))
    return {"input_sha256": sha256_file(csv_path), "rig_sha256": rig_hash,
            "fitlug_version": __version__, "command": f"fit-lug campaign ({opts})"}


def point_of_fit(res, name: str, verdict: str | None = None) -> dict:
    """The campaign point of a fitted recording: steady slip and local slope ds/da with
    their covariance (least-squares, delta method), under its final model; `verdict`: its
    explanation's ('none', 'explained', 'unexplained'; None without one)."""
    rig = res.problem.rig
    lay = res.problem.lay
    sl = res.packing.slices()
    keys = ["s0", "beta", "slide_mu"]
    vals = np.array([float(np.asarray(res.params.get(k, 0.0))) for k in keys])
    idx = [sl[k].start if k in sl else None for k in keys]
    C = np.zeros((3, 3))
    for a, i in enumerate(idx):
        for b, j in enumerate(idx):
            if i is not None and j is not None:
                C[a, b] = res.cov[i, j]
    sliding = "lug_sliding" in res.effects

    def f(v):
        s0, beta, mu = v
        if not sliding:
            return np.array([s0, beta])
        z = mu * s0
        lr = 1.0 if abs(z) < 1e-9 else -np.log1p(-z) / z
        return np.array([s0 * lr, beta / (1.0 - z)])

    y = f(vals)
    J = np.empty((2, 3))
    for j in range(3):
        h = 1e-6 * max(abs(vals[j]), 1e-6)
        vp, vm = vals.copy(), vals.copy()
        vp[j] += h
        vm[j] -= h
        J[:, j] = (f(vp) - f(vm)) / (2 * h)
    cov = J @ C @ J.T
    return {"name": name, "slip": float(y[0]), "slope": float(y[1]), "cov": cov.tolist(),
            "mass_kg": rig.mass_kg, "drawbar_pull_N": float(rig.drawbar_pull_N),
            "ground": rig.ground, "n": int(lay.n_contact), "L": float(lay.L),
            "effects": list(res.effects), "chi2_per_dof": float(res.chi2_per_dof),
            "verdict": verdict}


def fit_recording(csv_path: str, out_dir: str, *, rig_path: str | None = None, name=None,
                  seed: int = 0, explain: bool = True, mcmc: bool = True,
                  report: bool = True, mcmc_budget: float = 900.0, resume: bool = True,
                  recording=None, rig=None) -> dict:
    """Fit one recording into `out_dir` (fit.json, report.html) and return its summary:
    {"name", "input", "out", "status": "fitted" | "unchanged" | "failed", "error",
    "point", "slip", "seconds"}. Never raises for a bad recording: the error is returned
    as one line."""
    t0 = time.perf_counter()
    name = name or os.path.basename(os.path.normpath(out_dir))
    summary = {"name": name, "input": csv_path, "out": out_dir, "status": "failed",
               "error": None, "point": None, "seconds": 0.0}
    try:
        from .._errors import FitlugError
        from ..io import find_rig, read_rig, read_trajectories, write_json

        if rig is None:
            rig = read_rig(rig_path) if rig_path else find_rig(csv_path)
        options = {"seed": seed, "explain": explain, "mcmc": mcmc}
        prov = provenance(csv_path, rig, options)
        fj_path = os.path.join(out_dir, "fit.json")
        if resume and os.path.isfile(fj_path):
            try:
                with open(fj_path, encoding="utf-8") as fh:
                    old = json.load(fh)
            except (OSError, ValueError):
                old = {}
            if old.get("provenance") == prov and old.get("campaign_point"):
                summary.update(status="unchanged", point=old["campaign_point"],
                               slip=old.get("slip"), seconds=time.perf_counter() - t0)
                return summary
        if recording is None:
            recording = read_trajectories(csv_path, rig=rig)
        doc, final, post, expl = _fit_full(recording, rig, csv_path, seed=seed,
                                           explain=explain, mcmc=mcmc,
                                           mcmc_budget=mcmc_budget)
        verdict = (doc.get("discrepancy") or {}).get("verdict")
        point = point_of_fit(final, name, verdict)
        doc["provenance"] = prov
        doc["campaign_point"] = point
        os.makedirs(out_dir, exist_ok=True)
        write_json(fj_path, doc)
        if post is not None:
            post.save(os.path.join(out_dir, "posterior.nc"))
        if report:
            from ..report import save_state, write_report

            save_state(out_dir, final, posterior=post, explanation=expl)
            write_report(out_dir)
        summary.update(status="fitted", point=point, slip=doc.get("slip"))
    except FitlugError as exc:
        summary["error"] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    except Exception as exc:  # noqa: BLE001  (a failing recording must not stop the campaign)
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" ({os.path.basename(tb[-1].filename)}:{tb[-1].lineno})" if tb else ""
        msg = (str(exc).splitlines() or [""])[0]
        summary["error"] = f"{csv_path}: {type(exc).__name__}: {msg}{where}"
    summary["seconds"] = time.perf_counter() - t0
    return summary


def _fit_full(rec, rig, input_path, *, seed, explain, mcmc, mcmc_budget):
    """fit -> explain -> posterior -> fit.json dictionary (the library calls of fit-lug)."""
    from ..fit import fit
    from ..report import fit_json

    # without the explanation, the law's curvature is fitted in every recording (nested:
    # slide_mu = 0 is the linear law), so a sliding law does not bias the point
    res = fit(rec, rig) if explain else fit(rec, rig, effects=("lug_sliding",))
    final, expl = res, None
    if explain:
        from ..explain import explain as run_explain

        expl = run_explain(res, seed=seed, progress=False)
        final = expl.final
    post = None
    if mcmc:
        from ..posterior import sample_posterior

        post = sample_posterior(final, seed=seed, progress=False, time_budget_s=mcmc_budget)
    doc = fit_json(final, input_path=input_path,
                   posterior=None if post is None else post.estimates,
                   mcmc=None if post is None else post.mcmc_json(),
                   discrepancy=None if expl is None else expl.to_json())
    if post is None:
        doc["mcmc"] = None
        doc["mcmc_skipped"] = "campaign without posterior: uncertainties are least-squares errors"
    if not explain:
        doc["discrepancy_skipped"] = "campaign without explanation"
    return doc, final, post, expl

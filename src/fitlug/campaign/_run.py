"""`fitlug.campaign`: fit every recording (on Dask workers), then the shared slip law.

Sources are CSV files (their rig.toml beside them), folders (every CSV under them) and
glob patterns, or `Recording` objects (with their `Rig`). Each recording is fitted in full
by `fit_recording` into OUT/<name>/; the campaign model (`_model`) is fitted to the
recordings' points; campaign.json and campaign.html are written into OUT.

Here: `campaign` and the running of the per-recording jobs (in this process or on Dask).
The sources are expanded in `_sources`, the shared law fitted in `_law`, the result and
its files are `_result`'s.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import sys

import numpy as np

from .._errors import InputError
from . import _model
from ._job import fit_recording
from ._law import fit_points
from ._result import CampaignResult, RecordingOutcome, write_campaign
from ._sources import resolve_sources

Z95 = 1.959963984540054


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
             report: bool = True, resume: bool = True, mcmc_budget: float = 900.0,
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

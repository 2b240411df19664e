"""fitlug on recordings as a real camera and tracker deliver them. Prints figures; asserts nothing.

    python benchmarks/bench_realism.py [--n 50] [--n-effect 10] [--rows clean,glitched,fov,all]
        [--rows ...,rendered --n-rendered 4] [--effects lug_ripple,...] [--workers 4] [--out F]

Recordings come from tests/independent_sim.py (MODEL.md written independently; 120 fps,
5 s, 0.72 m of travel so the robot crosses a 637 mm picture), each with its own seed,
and go through the full default pipeline: fit (noise from the data, refit) then explain.
Rows (the transform is tests/realism.py):

- clean: as generated;
- glitched: 0.1-0.2 % of the samples moved by 0.5-1 mm (nothing else);
- fov: 637 mm field of view, 1 % misses, occlusions of 5-30 frames, ids split after gaps
  longer than 10 frames (new ids 'trkNN'), no glitches;
- all: everything above together, written in the wide export form with the roles in
  rig.toml, read back with fitlug.io;
- drive (issue 26): the robot drives through the picture: tests/realism.py's
  `drive_through` window of 300-637 mm placed anywhere along the travel (the robot outside
  the picture at the start, the end or both), markers lost within 0-8 mm of the edge, and
  another rig and speed profile per recording (`drive_scenario`: 100-250 fps, 5-8 s,
  n, L, R, pitch, belt, mass, k, C_rr, markers drawn); every other recording also gets
  every fault of the fov row plus glitches. Effects that need a place in time or in the
  picture are put in the window (frame_drop's t* mid-way through what is seen; the lens
  centre at the window's centre). With --twins, each recording's in-view twin (the same
  recording and faults, no window) is fitted too and the verdicts compared.
- rendered (only when asked for: --rows ...,rendered): the noise-free recording rendered as
  camera frames by fitlug.sim.render_video (637 mm x 117 mm picture at 0.39 mm/px: the
  robot crosses it; lens, motion blur, lighting gradient, vignetting, sensor noise),
  tracked by fitlug.vision.track (what `fit-lug track` runs) and mapped to mm with the
  calib.json the renderer wrote; about a minute per recording, so --n-rendered (default 4)
  recordings per case instead of --n / --n-effect.

- tracker (issue 42): the noise-free recording with a centroid tracker's correlated error
  (tests/realism.py `tracker_error`: pixel locking 0.004-0.012 px at 0.2-0.45 mm/px, a
  slow per-marker drift of 1-3 um over 0.3-1.5 s, read noise 1.5-6 um), seen through the
  fov row's picture (misses, occlusions, split ids; no glitches). Its `claims` column
  counts false physical claims: a null with any effect named or a family term kept, an
  effect recording with anything named beside its own.

Per row: failures (exceptions), false-alarm rate (clean physics, verdict other than
'none'), the slip's bias and mean z = (s0 - truth) / std over the null recordings, and
per catalog effect the detection rate (verdict 'explained' naming exactly that effect)
over `--n-effect` recordings each. Recordings run in parallel over `--workers` processes
(spawn: JAX is never forked).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

# the effects and sizes of the blind test of the independent generator (one table for both)
from test_explain_independent import CASES, FPS  # noqa: E402

EFFECTS = {k: v for k, v in CASES.items() if len(v) == 1}
ROWS = ("clean", "glitched", "fov", "all", "drive", "tracker")
RENDER_SIZE = (1632, 300)  # px: 637 mm wide at 0.39 mm/px, 117 mm high (the markers' band)


def rendered(rec, seed: int):
    """`rec` (noise-free positions) rendered as frames, tracked and mapped back to mm."""
    from fitlug.sim import render_video
    from fitlug.vision import load_calibration, to_recording, track

    t = np.unique(rec.t)
    xy = np.full((t.size, rec.n_markers, 2), np.nan)
    row = np.searchsorted(t, rec.t)
    xy[row, rec.marker_index, 0] = rec.x
    xy[row, rec.marker_index, 1] = rec.y
    with tempfile.TemporaryDirectory() as d:
        info = render_video(d, t, list(rec.markers), list(rec.roles), xy,
                            image_size=RENDER_SIZE, seed=seed, progress=False)
        result = track(d, fps=float(1.0 / np.median(np.diff(t))))
        return to_recording(result, load_calibration(info["calib"]))


def transform(row: str, rec, rig, seed: int):
    """The recording of `row` (and the rig to fit it with)."""
    from realism import realistic, write_realistic

    if row == "clean":
        return rec, rig
    if row == "glitched":
        out, _ = realistic(rec, seed=seed, fov_mm=None, miss=0.0, occlusion_rate=0.0,
                           glitches=True, split_gap_frames=None, rename=False)
        return out, rig
    if row == "fov":
        out, _ = realistic(rec, seed=seed, glitches=False)
        return out, rig
    if row == "tracker":
        from realism import tracker_error

        out, _ = tracker_error(rec, seed=seed)
        out, _ = realistic(out, seed=seed, glitches=False)
        return out, rig
    if row == "all":
        from fitlug.io import read_rig, read_trajectories

        out, _ = realistic(rec, seed=seed, glitches=True)
        with tempfile.TemporaryDirectory() as d:
            path = write_realistic(d, out, rig, wide=True)
            rig2 = read_rig(os.path.join(d, "rig.toml"))
            return read_trajectories(path, rig=rig2), rig2
    raise ValueError(row)


def drive(effect, seed: int, twins: bool = False):
    """The drive row's recording: (recording through the window, rig, truth, in-view twin
    or None, info)."""
    import independent_sim as isim
    from realism import drive_scenario, drive_through

    kw = drive_scenario(seed)
    faults = seed % 2 == 0
    rec, rig, truth = isim.make(seed, **kw)
    cut, info = drive_through(rec, seed=seed, faults=faults)
    if effect:
        eff = {k: dict(v) for k, v in EFFECTS[effect].items()}
        ok = np.isfinite(cut.x)
        t0, t1 = float(cut.t[ok].min()), float(cut.t[ok].max())
        if effect == "frame_drop":
            eff["frame_drop"] = {"drop_dt": 1.0 / kw["fps"], "drop_tstar": round(
                0.5 * (t0 + t1) * kw["fps"]) / kw["fps"]}
        if effect == "lens_distortion":
            eff["lens_distortion"]["lens_cx"] = 0.5 * sum(info["window"])
        rec, rig, truth = isim.make(seed, effects=eff, **kw)
        cut, info = drive_through(rec, seed=seed, faults=faults, window=info["window"])
    twin = None
    if twins:
        from realism import realistic

        opts = {} if faults else dict(miss=0.0, occlusion_rate=0.0, glitches=False,
                                      split_gap_frames=None, rename=False)
        twin, _ = realistic(rec, seed=seed, fov_mm=None, **opts)
    info["faults"] = faults
    info["fps"] = kw["fps"]
    return cut, rig, truth, twin, info


def one(task):
    """Fit and explain one recording: a dict of what came out (never raises)."""
    row, effect, seed = task[:3]
    twins = len(task) > 3 and task[3]
    import independent_sim as isim

    from fitlug.explain import explain
    from fitlug.fit import fit

    t0 = time.perf_counter()
    if row == "drive":
        out = {"row": row, "effect": effect, "seed": seed}
        try:
            rec2, rig2, truth, twin, info = drive(effect, seed, twins)
            ok = np.isfinite(rec2.x)
            out.update(truth=truth["slip"], window=[round(v, 1) for v in info["window"]],
                       seen_s=[float(rec2.t[ok].min()), float(rec2.t[ok].max())],
                       faults=bool(info["faults"]), fps=info["fps"])
            for key, r in (("", rec2), ("twin_", twin)):
                if r is None:
                    continue
                ex = explain(fit(r, rig2))
                fin = ex.final
                out.update({key + "verdict": ex.verdict, key + "named": sorted(ex.effects),
                            key + "terms": [d.get("family", "") for d in ex.discovered],
                            key + "slip": float(fin.slip.value),
                            key + "std": float(fin.slip.std),
                            key + "chi2": float(fin.chi2_per_dof)})
        except Exception as exc:  # noqa: BLE001 - a benchmark counts failures
            out["error"] = f"{type(exc).__name__}: {exc}"[:300]
        out["seconds"] = time.perf_counter() - t0
        return out
    eff = EFFECTS.get(effect) if effect else None
    noise = {"noise_lug": 0.0, "noise_body": 0.0} if row in ("rendered", "tracker") else {}
    rec, rig, truth = isim.make(seed, fps=FPS, v_max=240.0, effects=eff, **noise)
    out = {"row": row, "effect": effect, "seed": seed, "truth": truth["slip"]}
    try:
        if row == "rendered":  # the camera adds the noise
            rec2, rig2 = rendered(rec, seed), rig
        else:
            rec2, rig2 = transform(row, rec, rig, seed)
        res = fit(rec2, rig2)
        ex = explain(res)
        fin = ex.final
        out.update(verdict=ex.verdict, named=sorted(ex.effects), slip=float(fin.slip.value),
                   terms=[d.get("family", "") for d in ex.discovered],
                   std=float(fin.slip.std), chi2=float(fin.chi2_per_dof),
                   n_markers_in=len(rec2.markers), n_markers_fit=len(res.problem.rec.markers))
    except Exception as exc:  # noqa: BLE001 - a benchmark counts failures
        out["error"] = f"{type(exc).__name__}: {exc}"[:300]
    out["seconds"] = time.perf_counter() - t0
    return out


def summarise(results, rows, effects):
    print(f"{'row':10s} {'n':>4s} {'fail':>5s} {'false alarm':>12s} {'slip bias':>11s} "
          f"{'mean z':>7s} {'rms z':>6s}  detection per effect")
    for row in rows:
        null = [r for r in results if r["row"] == row and r["effect"] is None]
        ok = [r for r in null if "error" not in r]
        fa = np.mean([r["verdict"] != "none" for r in ok]) if ok else float("nan")
        z = np.array([(r["slip"] - r["truth"]) / r["std"] for r in ok])
        bias = np.mean([r["slip"] - r["truth"] for r in ok]) if ok else float("nan")
        det = []
        for e in effects:
            rs = [r for r in results if r["row"] == row and r["effect"] == e]
            hit = sum(1 for r in rs if "error" not in r and r["named"] == [e])
            det.append(f"{e}={hit}/{len(rs)}")
        nfail = sum(1 for r in results if r["row"] == row and "error" in r)
        print(f"{row:10s} {len(null):4d} {nfail:5d} {fa:12.3f} {bias:11.2e} "
              f"{(z.mean() if len(z) else np.nan):7.2f} "
              f"{(np.sqrt(np.mean(z ** 2)) if len(z) else np.nan):6.2f}  {' '.join(det)}")
    for row in rows:
        done = [r for r in results if r["row"] == row and "error" not in r and "named" in r]
        if done:
            false = [r for r in done if _false_claim(r)]
            print(f"{row}: false physical claims in {len(false)}/{len(done)} recordings "
                  f"(a null naming anything or keeping a family term; an effect recording "
                  f"naming another)" + "".join(
                      f"\n  seed {r['seed']} {r['effect'] or 'null'}: {r['verdict']} "
                      f"{r['named']} {r.get('terms', '')}" for r in false[:10]))
    for row in rows:
        allr = [r for r in results if r["row"] == row and "error" not in r and "std" in r]
        if allr:
            z = np.array([(r["slip"] - r["truth"]) / r["std"] for r in allr])
            print(f"{row}: slip within 3 reported sigma of the truth in "
                  f"{int(np.sum(np.abs(z) <= 3))}/{len(z)} recordings (nulls and effects; "
                  f"within 2 sigma: {int(np.sum(np.abs(z) <= 2))}/{len(z)})")
    twin = [r for r in results if "twin_verdict" in r and "error" not in r]
    if twin:
        same = sum(1 for r in twin if (r["verdict"], r["named"])
                   == (r["twin_verdict"], r["twin_named"]))
        print(f"drive-through vs in-view twin: same verdict and named effects {same}/"
              f"{len(twin)}")
    errs = [r for r in results if "error" in r]
    for r in errs[:10]:
        print(f"  failure {r['row']}/{r['effect']}/seed {r['seed']}: {r['error']}")


def _false_claim(r) -> bool:
    """A claim of physics the recording does not hold (issue 42): any named effect but the
    recording's own, or a family term (or verdict 'modelled')."""
    own = {r["effect"]} if r["effect"] else set()
    return bool(set(r["named"]) - own) or r["verdict"] == "modelled" or bool(r.get("terms"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="null recordings per row")
    ap.add_argument("--n-effect", type=int, default=10, help="recordings per effect per row")
    ap.add_argument("--n-rendered", type=int, default=4,
                    help="null recordings and recordings per effect of the rendered row")
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--out", default=None, help="write every result as JSON")
    ap.add_argument("--log", default=None,
                    help="append one JSON line per recording as it finishes (a run cut short "
                         "keeps what it did)")
    ap.add_argument("--from-log", default=None, help="summarise a --log file, no new fits")
    ap.add_argument("--twins", action="store_true",
                    help="drive row: also fit each recording's in-view twin")
    a = ap.parse_args(argv)
    rows = [r for r in a.rows.split(",") if r]
    effects = [e for e in a.effects.split(",") if e] if a.n_effect > 0 else []
    if a.from_log:
        with open(a.from_log) as fh:
            results = [json.loads(line) for line in fh if line.strip()]
        print(f"{len(results)} recordings from {a.from_log}")
        summarise(results, rows, effects)
        return
    tasks = []
    for row in rows:
        n, n_eff = (a.n_rendered, a.n_rendered) if row == "rendered" else (a.n, a.n_effect)
        tw = (a.twins,) if row == "drive" else ()
        tasks += [(row, None, a.seed0 + k) + tw for k in range(n)]
        for i, e in enumerate(effects):
            tasks += [(row, e, a.seed0 + 10000 * (i + 1) + k) + tw for k in range(n_eff)]
    # interleave rows and effects, so that a run cut short has a bit of every row
    tasks = sorted(tasks, key=lambda t: (t[2] % 10000, t[0], t[1] or ""))
    t0 = time.perf_counter()
    log = open(a.log, "a") if a.log else None

    def keep(r):
        if log is not None:
            log.write(json.dumps(r) + "\n")
            log.flush()
        return r

    if a.workers > 1:
        from _workers import one_thread_each

        one_thread_each()
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(a.workers, mp_context=ctx) as ex:
            futures = [ex.submit(one, t) for t in tasks]
            results = [keep(f.result()) for f in as_completed(futures)]
    else:
        results = [keep(one(t)) for t in tasks]
    print(f"{len(tasks)} recordings in {time.perf_counter() - t0:.0f} s with "
          f"{a.workers} worker(s)")
    summarise(results, rows, effects)
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()

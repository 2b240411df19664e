"""How well and how fast fitlug.explain finds left-out physics. Prints figures; asserts nothing.

    python benchmarks/bench_explain.py [--part speed,far,ladder,limit,concealed] [--clean 20]
        [--seeds 4] [--effects lug_ripple,...] [--out results.json]

1. speed: wall and CPU time of explain() on a 650-frame recording with a hidden lug
   ripple (the base fit is not counted), first call in the process (tracing, disk cache
   warm after the first run) and a second call.
2. far: false-alarm rate on clean simulations (verdict other than 'none'), each with its
   own seed, plus the detector alone on residuals drawn from the fit's linearised null
   (white noise projected out of the Jacobian, noise re-estimated) for a sharper figure.
3. ladder: per effect, the smallest amplitude found 90 % of the time. Amplitudes are a
   coarse ladder of multiples of a per-effect reference size (x1, x2, x4 of a rough
   threshold), `--seeds` recordings per rung; found means verdict 'explained' with
   exactly that effect. A rung stops early once more than 10 % are missed, and the ladder
   stops at the first rung found >= 90 % of the time. The amplitude in units of the
   noise is the RMS over all samples of the effect's noise-free displacement divided by
   the noise sigma of each role.
4. limit (not in the default set): lug_sliding up to the friction limit (issue 32): the
   light track of fitlug.sim LIMIT_* (k 0.0524 N/mm, F_max 5 N, 1.5 kg) pulled to steady
   slips 0.06 .. 0.40 (F0/F_max 0.28 .. 0.88; the last one's acceleration ramp peaks at 0.97 F_max), short recordings (4 s at
   60 fps); per load and seed the verdict, whether lug_sliding alone is named, chi^2/dof
   and (truth - estimate)/std of s_K, k, C_rr and the slip.
5. concealed (not in the default set): every data/concealed recording explained blind
   (tests/test_concealed.py keeps those no other test checks; issue 43).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "src"))

from fitlug.explain import explain  # noqa: E402
from fitlug.fit import fit  # noqa: E402
from fitlug.sim import Scenario, rig_of, simulate  # noqa: E402


from _ladder_table import LADDER, _mod  # noqa: E402

RUNGS = (1.0, 2.0, 4.0)


def noise_units(sc: Scenario) -> float:
    """RMS of the effects' noise-free displacement over all samples, in noise sigmas."""
    quiet = dict(noise_lug_mm=0.0, noise_body_mm=0.0)
    a, _ = simulate(sc.replace(**quiet), 0)
    b, _ = simulate(sc.replace(effects={}, **quiet), 0)
    sig = np.where(np.asarray(a.roles)[a.marker_index] == "lug", sc.noise_lug_mm,
                   sc.noise_body_mm)
    d2 = ((a.x - b.x) ** 2 + (a.y - b.y) ** 2) / sig ** 2
    return float(np.sqrt(np.mean(d2) / 2))


def run_one(sc: Scenario, seed: int):
    rec, truth = simulate(sc, seed)
    res = fit(rec, rig_of(sc))
    t0, c0 = time.perf_counter(), time.process_time()
    ex = explain(res)
    return ex, truth, time.perf_counter() - t0, time.process_time() - c0


def part_speed(out):
    sc = Scenario(effects={"lug_ripple": _mod(0.003, 1.0, "ripple")})
    rec, _ = simulate(sc, 7)
    res = fit(rec, rig_of(sc))
    rows = []
    for call in ("first", "second"):
        t0, c0 = time.perf_counter(), time.process_time()
        ex = explain(res)
        rows.append({"call": call, "wall_s": time.perf_counter() - t0,
                     "cpu_s": time.process_time() - c0, "verdict": ex.verdict,
                     "effects": ex.effects, "steps": ex.timing_s})
        print(f"speed: {call} call {rows[-1]['wall_s']:.1f} s wall, {rows[-1]['cpu_s']:.1f} s "
              f"CPU -> {ex.verdict} {ex.effects}; {json.dumps(ex.timing_s)}", flush=True)
    out["speed"] = {"frames": 650, "cores": os.cpu_count(), "load_avg": os.getloadavg(),
                    "runs": rows}


def part_far(out, n_clean, n_null):
    alarms, rows = 0, []
    for seed in range(1000, 1000 + n_clean):
        ex, truth, wall, cpu = run_one(Scenario(), seed)
        alarms += ex.verdict != "none"
        d = ex.detection_before
        rows.append({"seed": seed, "verdict": ex.verdict, "effects": ex.effects,
                     "p": [d.chi2_p, d.ljung_box_p, d.periodogram_p, d.line_p],
                     "slip_z": (ex.final.slip.value - truth["slip"]) / ex.final.slip.std})
        print(f"far: seed {seed} -> {ex.verdict} {ex.effects} p={np.round(rows[-1]['p'], 3)} "
              f"slip z {rows[-1]['slip_z']:+.2f}", flush=True)
    lo, hi = _binom_ci(alarms, n_clean)
    out["false_alarms"] = {"clean_recordings": n_clean, "alarms": alarms,
                           "rate": alarms / max(n_clean, 1), "ci95": [lo, hi], "runs": rows}
    print(f"false-alarm rate on {n_clean} clean recordings: {alarms}/{n_clean} "
          f"(95 % CI {lo:.3f}-{hi:.3f})", flush=True)
    if n_null:
        rate = _linearised_null(n_null)
        out["false_alarms"]["linearised_null"] = {"draws": n_null, "rate": rate}
        print(f"false-alarm rate of the detector on {n_null} linearised-null residual sets: "
              f"{rate:.3f}", flush=True)


def _linearised_null(n):
    from fitlug.explain import detect, geometry
    from fitlug.explain._engine import Engine
    from fitlug.fit._noise import fourth_differences, noise_from_differences

    rec, _ = simulate(Scenario(), 999)
    res = fit(rec, rig_of(Scenario()))
    geo = geometry(res)
    eng = Engine(res)
    J = eng.base_jacobian(eng.theta0)
    U = np.linalg.svd(J, full_matrices=False)[0]
    rng = np.random.default_rng(5)
    alarms = 0
    for _ in range(n):
        e = rng.normal(size=J.shape[0])
        r = e - U @ (U.T @ e)
        for role in (0, 1):  # the noise re-estimated from these residuals, as fit() does
            diffs = []
            for s in geo.series_ids():
                sel = np.flatnonzero((geo.series == s) & (geo.role == role))
                if len(sel):
                    sel = sel[np.argsort(geo.t[sel])]
                    diffs.append(fourth_differences(geo.t[sel], r[sel]))
            r = np.where(geo.role == role, r / noise_from_differences(diffs)[0], r)
        alarms += not detect(geo, r, res.dof).consistent
    return alarms / n


def _binom_ci(k, n):
    from scipy import stats

    lo = stats.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def part_ladder(out, effects, seeds, rungs=RUNGS):
    res_all = {}
    for eid in effects:
        make, thr = LADDER[eid]
        rows = []
        for k, f in enumerate(rungs):
            sc = Scenario(effects=make(thr * f))
            units = noise_units(sc)
            found = tried = 0
            for s in range(seeds):
                ex, truth, wall, _ = run_one(sc, 2000 + 100 * k + s)
                found += ex.verdict == "explained" and ex.effects == [eid]
                tried += 1
                if tried - found > 0.1 * seeds:  # this rung can no longer reach 90 %
                    break
            rows.append({"size": thr * f, "noise_units": units, "found": found, "of": tried,
                         "planned": seeds})
            print(f"ladder: {eid} size {thr * f:.3g} ({units:.3f} sigma rms): "
                  f"{found}/{tried} found" + (" (stopped: > 10 % missed)" if tried < seeds
                                              else ""), flush=True)
            if found >= 0.9 * seeds:  # larger sizes are found at least as often
                break
        ok = [r for r in rows if r["found"] >= 0.9 * r["planned"]]
        res_all[eid] = {"rungs": rows,
                        "smallest_found_90pct_noise_units": ok[0]["noise_units"] if ok else None,
                        "smallest_found_90pct_size": ok[0]["size"] if ok else None}
        print(f"ladder: {eid}: smallest amplitude found >= 90 %: "
              f"{res_all[eid]['smallest_found_90pct_noise_units']} sigma rms", flush=True)
    out["ladder"] = {"seeds_per_rung": seeds, "rungs": list(rungs), "effects": res_all}


LIMIT_SLIPS = (0.061, 0.109, 0.172, 0.268, 0.396)


def part_limit(out, seeds):
    from fitlug.sim._campaign import LIMIT_K, SMALL_BASE

    n, L, m, crr, F_max = 8, 127.0, 1.5, 0.06, 5.0
    s_K = 2 * F_max / (LIMIT_K * n * L)
    base = SMALL_BASE.replace(duration_s=4.0, fps=60.0, travel_mm=400.0, ramp_s=0.8)
    rows = []
    print("limit: s0  F0/Fmax seed verdict named chi2/dof  z(s_K) z(k) z(C_rr) z(slip)  s")
    for s0 in LIMIT_SLIPS:
        F0 = F_max * (1 - math.exp(-s0 / s_K))
        for seed in range(seeds):
            sc = base.replace(mass_kg=m, rolling_resistance=crr, drawbar_pull_N=F0 - m * crr * 9.81,
                              slip=2 * F0 / (LIMIT_K * n * L),
                              effects={"lug_sliding": {"slide_mu": 1 / s_K}})
            rec, tr = simulate(sc, seed=100 + seed)
            t0 = time.perf_counter()
            ex = explain(fit(rec, rig_of(sc)))
            dt = time.perf_counter() - t0
            doc = ex.to_json()
            q = ex.final.quantities

            def z(est, want):
                return (est.value - want) / est.std if est is not None and est.std else None

            zs = None
            for e in doc["effects"]:
                if e["id"] == "lug_sliding" and e["params_std"]:
                    zs = (e["params"]["s_K"] - s_K) / e["params_std"]["s_K"]
            row = {"s0": s0, "F0_over_Fmax": F0 / F_max, "seed": seed, "verdict": ex.verdict,
                   "named": ex.effects, "chi2_per_dof": float(ex.final.chi2_per_dof),
                   "z_sK": zs, "z_k": z(q["stiffness_N_per_mm"], LIMIT_K),
                   "z_crr": z(q["rolling_resistance"], crr), "z_slip": z(q["slip"], tr["slip"]),
                   "seconds": dt}
            rows.append(row)
            f = lambda v: "   -  " if v is None else f"{v:6.2f}"  # noqa: E731
            print(f"  {s0:.3f} {F0 / F_max:.2f} {seed} {ex.verdict:11s} {','.join(ex.effects):24s}"
                  f" {row['chi2_per_dof']:7.2f} {f(zs)} {f(row['z_k'])} {f(row['z_crr'])}"
                  f" {f(row['z_slip'])} {dt:5.0f}", flush=True)
    ok = [r for r in rows if r["verdict"] == "explained" and r["named"] == ["lug_sliding"]
          and all(v is not None and abs(v) <= 3 for v in
                  (r["z_sK"], r["z_k"], r["z_crr"], r["z_slip"]))]
    print(f"limit: {len(ok)}/{len(rows)} explained by lug_sliding alone, all four covered (3 sd)")
    out["limit"] = rows


def part_concealed(out):
    """Every data/concealed recording explained blind, as tests/test_concealed.py does for
    those it keeps: verdict and effects against the truth, slip within 3 sd, time (the
    three it left out for CI time, issue 43: belt_sag, frame_drop, sinkage+frame_drop)."""
    from fitlug.io import find_rig, read_trajectories

    root = os.path.join(os.path.dirname(__file__), "..", "data", "concealed")
    rows = []
    for folder in sorted(d for d in os.listdir(root) if d.startswith("rec")):
        csv = os.path.join(root, folder, "trajectories.csv")
        rig = find_rig(csv)
        t0, c0 = time.perf_counter(), time.process_time()
        ex = explain(fit(read_trajectories(csv, rig=rig), rig))
        with open(os.path.join(root, folder, "truth.json")) as fh:
            truth = json.load(fh)
        want = truth["concealed"]
        ok = (ex.verdict, sorted(ex.effects)) == (want["verdict"], want["effects"])
        z = (ex.final.slip.value - truth["slip"]) / ex.final.slip.std
        rows.append({"folder": folder, "case": want["case"], "right": ok, "slip_z": z,
                     "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0})
        print(f"concealed {folder} {want['case']:<20} {'right' if ok else 'WRONG':5} "
              f"({ex.verdict}, {ex.effects}) slip z {z:+.2f}  {rows[-1]['cpu_s']:.0f} s CPU",
              flush=True)
    print(f"concealed: {sum(r['right'] for r in rows)}/{len(rows)} right, "
          f"{sum(abs(r['slip_z']) <= 3 for r in rows)}/{len(rows)} slips within 3 sd")
    out["concealed"] = rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="speed,far,ladder")
    ap.add_argument("--clean", type=int, default=20)
    ap.add_argument("--null", type=int, default=400)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--effects", default=",".join(LADDER))
    ap.add_argument("--rungs", default=",".join(f"{r:g}" for r in RUNGS),
                    help="multiples of each effect's reference size")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    out = {}
    parts = args.part.split(",")
    if "speed" in parts:
        part_speed(out)
    if "far" in parts:
        part_far(out, args.clean, args.null)
    if "ladder" in parts:
        part_ladder(out, args.effects.split(","), args.seeds,
                    tuple(float(r) for r in args.rungs.split(",")))
    if "limit" in parts:
        part_limit(out, args.seeds)
    if "concealed" in parts:
        part_concealed(out)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(out, fh, indent=1, default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

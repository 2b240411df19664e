"""Silent wrong answers (issue 30): each fault a tracker, rig file or user could bring is
found and repaired, kept out and listed, or refused in one line; never a confident wrong
answer. Truth: the bundled reference recording (its clean answer and truth.json) changed
as the fault would change it, and fitlug.sim's recordings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from fitlug._errors import InputError
from fitlug.io import read_rig, read_trajectories, write_trajectories

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REF_DIR = os.path.join(ROOT, "data", "reference")
REF = os.path.join(REF_DIR, "trajectories.csv")


@pytest.fixture(scope="module")
def ref():
    return read_trajectories(REF)


def _swap(rec, a, b, t0, t1=np.inf):
    """`rec` with markers a and b exchanging ids for t0 <= t < t1 (a tracker's swap)."""
    A, B = rec.markers.index(a), rec.markers.index(b)
    mi = rec.marker_index.copy()
    span = (rec.t >= t0) & (rec.t < t1)
    ia, ib = span & (mi == A), span & (mi == B)
    mi[ia], mi[ib] = B, A
    return _sorted(rec, mi)


def _sorted(rec, mi, **extra):
    o = np.lexsort((rec.t if "t" not in extra else extra["t"], mi))
    fields = {k: (extra.get(k, getattr(rec, k)))[o] for k in ("t", "x", "y", "frame", "sigma")
              if extra.get(k, getattr(rec, k)) is not None}
    return rec.with_(marker_index=mi[o], **fields)


def _add(rec, name, role, t, x, y):
    """`rec` with one more track (a reflection the tracker followed)."""
    t = np.asarray(t, float)
    k = rec.n_markers
    fps = 100.0
    return rec.with_(markers=rec.markers + (name,), roles=rec.roles + (role,),
                     marker_index=np.r_[rec.marker_index, np.full(t.size, k)],
                     t=np.r_[rec.t, t], x=np.r_[rec.x, np.broadcast_to(x, t.shape)],
                     y=np.r_[rec.y, np.broadcast_to(y, t.shape)],
                     frame=np.r_[rec.frame, np.rint(t * fps).astype(np.int64)])


# -- rig.toml: keys in the wrong place -------------------------------------------------------

RIG_MISPLACED = [
    ("lugs_in_contact = 6\nload_bearing_length_mm = 100\n", 1,
     "top level.*'lugs_in_contact' belongs under \\[track\\]"),
    ("[vehicle]\nlugs_in_contact = 6\n", 2,
     "\\[vehicle\\].*'lugs_in_contact' belongs under \\[track\\]"),
    ("[vehicle]\nmass = 10\n", 2, "\\[vehicle\\].*'mass'.*did you mean 'mass_kg'"),
    ("mass = 10\n", 1, "'mass'.*did you mean 'mass_kg' under \\[vehicle\\]"),
    ("L = 100\n[track]\nlugs_in_contact = 6\n", 1,
     "'L'.*'load_bearing_length_mm' under \\[track\\]"),
    ("[track]\nlugs_in_contacts = 9\n", 2, "did you mean 'lugs_in_contact'"),
    ("[robot]\nmass_kg = 3\n", 2, "\\[robot\\].*'mass_kg' belongs under \\[vehicle\\]"),
    ("[camera]\nlug_pitch_mm = 18.36\n", 2, "belongs under \\[track\\]"),
]


@pytest.mark.parametrize("text, line, pattern", RIG_MISPLACED)
def test_rig_key_in_the_wrong_place_is_refused_naming_where_it_belongs(tmp_path, text, line,
                                                                        pattern):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=pattern) as err:
        read_rig(path)
    assert str(err.value).startswith(f"{path}:{line}: ") and "\n" not in str(err.value)


def test_rig_free_keys_stay_free(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text('note = "bench 3"\n[track]\nlugs_in_contact = 6\n[camera]\nmodel = "v9"\n'
                    '[lighting]\nlamps = 2\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rig = read_rig(path)
    assert rig.lugs_in_contact == 6
    assert rig.extra == {"note": "bench 3", "camera": {"model": "v9"}, "lighting": {"lamps": 2}}


def test_rig_markers_contradicting_the_file_are_refused(tmp_path, ref):
    (tmp_path / "rig.toml").write_text('[markers]\nbody = ["C1", "B03"]\n')
    rig = read_rig(tmp_path / "rig.toml")
    with pytest.raises(InputError, match=r"rig\.toml:2: \[markers\] body lists B03, but "
                                         r".*trajectories\.csv line 7 gives B03 the role lug"):
        read_trajectories(REF, rig=rig)
    (tmp_path / "rig.toml").write_text('[markers]\nbody = ["C1", "C2"]\nlug = ["B03"]\n')
    assert read_trajectories(REF, rig=read_rig(tmp_path / "rig.toml")) == ref


# -- the file's header: units ----------------------------------------------------------------

@pytest.mark.parametrize("unit, scale", [("in", 25.4), ("cm", 10.0), ("m", 1000.0),
                                         ("mm, s", 1.0)])
def test_units_header_is_honoured(tmp_path, ref, unit, scale):
    path = tmp_path / "trajectories.csv"
    write_trajectories(path, ref.with_(x=ref.x / scale, y=ref.y / scale,
                                       meta={**ref.meta, "units": unit}))
    rec = read_trajectories(path)
    np.testing.assert_allclose(rec.x, ref.x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rec.y, ref.y, rtol=1e-12, atol=1e-12)
    assert rec.meta["units"] == ("mm" if scale != 1.0 else unit)


@pytest.mark.parametrize("unit, pattern", [("px", "pixels"), ("furlong", "unknown unit"),
                                           ("mm, ms", "seconds")])
def test_units_header_not_honoured_is_refused_naming_the_line(tmp_path, ref, unit, pattern):
    path = tmp_path / "trajectories.csv"
    write_trajectories(path, ref.with_(meta={**ref.meta, "units": unit}))
    with pytest.raises(InputError, match=f"trajectories.csv:3: # units: {unit} - .*{pattern}"):
        read_trajectories(path)


# -- two runs in one file --------------------------------------------------------------------

def test_two_runs_in_one_file_are_refused_naming_the_line(tmp_path, ref):
    T = float(ref.t.max()) + 0.01
    n = ref.n_samples
    two = ref.with_(t=np.r_[ref.t, ref.t + T],
                    marker_index=np.r_[ref.marker_index, ref.marker_index],
                    x=np.r_[ref.x, ref.x], y=np.r_[ref.y, ref.y],
                    frame=np.r_[ref.frame, ref.frame + 650])
    two = _sorted(two, two.marker_index)
    assert two.n_samples == 2 * n
    path = tmp_path / "trajectories.csv"
    write_trajectories(path, two)
    with pytest.raises(InputError, match=r"two recordings in one file\? at time_s = 6\.5 every "
                                         r"body marker \(C1, C2\) jumps by \(-700"):
        read_trajectories(path)
    # the line named is the first row of the second run
    with pytest.raises(InputError) as err:
        read_trajectories(path)
    lines = path.read_text().splitlines()
    assert lines[err.value.line - 1].startswith("6.5,")
    # the in-memory guard of the fit says the same
    from fitlug.fit import build_problem

    with pytest.raises(InputError, match="two recordings in one file"):
        build_problem(two, read_rig(os.path.join(REF_DIR, "rig.toml")))


# -- the data's own frame: direction, y down, swapped axes -------------------------------------

@pytest.mark.parametrize("how", ["mirror", "y_down", "both", "swapped", "swapped_down"])
def test_orientation_is_found_from_the_data(ref, how):
    from fitlug.fit._orient import orient

    x, y = ref.x, ref.y
    changed = {"mirror": (-x, y), "y_down": (x, -y), "both": (-x, -y), "swapped": (y, x),
               "swapped_down": (-y, x)}[how]
    rec, info = orient(ref.with_(x=changed[0], y=changed[1]))
    assert np.array_equal(rec.x, ref.x) and np.array_equal(rec.y, ref.y)
    assert info["direction"] == ("-x" if how in ("mirror", "both") else "+x")
    assert info["y_axis"] == ("down" if how in ("y_down", "both", "swapped_down") else "up")
    assert info["axes_swapped"] == how.startswith("swapped")
    assert orient(ref)[1]["applied"] == []


# -- identity swaps --------------------------------------------------------------------------

@pytest.mark.parametrize("swaps", [[("B01", "B02", 3.0)], [("B01", "B05", 1.0, 2.0)],
                                   [("C1", "C2", 2.5)], [("B03", "B08", 0.5), ("B09", "B10", 4.0)]])
def test_identity_swaps_are_repaired_exactly(ref, swaps):
    from fitlug.fit._swaps import find_and_repair

    rec = ref
    for s in swaps:
        rec = _swap(rec, *s)
    fixed, found = find_and_repair(rec)
    assert fixed == ref
    got = {(tuple(sorted(f["markers"])), f["t_s"]) for f in found}
    want = {(tuple(sorted(s[:2])), t) for s in swaps for t in s[2:]}
    assert got == want


def test_three_ids_permuted_in_one_frame_are_repaired(ref):
    from fitlug.fit._swaps import find_and_repair

    rec = _swap(_swap(ref, "B01", "B02", 3.0), "B03", "B01", 3.0)  # a 3-cycle at 3 s
    fixed, found = find_and_repair(rec)
    assert fixed == ref
    assert [(sorted(f["markers"]), f["t_s"]) for f in found] == [(["B01", "B02", "B03"], 3.0)]


# -- tracks that are not markers -------------------------------------------------------------

def test_reflections_and_static_points_are_kept_out(ref):
    from fitlug.fit._spurious import find_and_exclude

    assert find_and_exclude(ref)[1] == []
    tt = np.array([3.0, 3.01, 3.02])
    cases = {"B99": _add(ref, "B99", "lug", tt, 300.0, 40.0),  # 3 frames above the track
             "B98": _add(ref, "B98", "lug", tt, 500.0, 2.0),  # on the ground, ahead
             "C9": _add(ref, "C9", "body", np.arange(200, 300) / 100, 250.0, 70.0),  # 1 s static
             "C8": _add(ref, "C8", "body", tt, 250.0, 70.0),  # 3 frames static
             "C7": _add(ref, "C7", "body", np.arange(650) / 100, np.linspace(0, 300, 650), 60.0)}
    for name, rec in cases.items():
        kept, listed = find_and_exclude(rec)
        assert [x["marker"] for x in listed] == [name], name
        assert kept == ref, name


SCENARIOS = [dict(), dict(fps=500.0, duration_s=2.0, travel_mm=300.0, rest_s=0.2, ramp_s=0.4),
             dict(lug_markers=6, lug_spacing=3, body_markers=((-60.0, 75.0), (0.0, 90.0),
                                                               (60.0, 75.0))),
             dict(noise_lug_mm=0.03, noise_body_mm=0.02, fps=200.0)]


@pytest.mark.parametrize("kw", SCENARIOS)
def test_simulated_recordings_raise_no_false_alarm_and_faults_are_found(kw):
    from fitlug.fit._prepare import prepare
    from fitlug.sim import Scenario, rig_of, simulate

    sc = Scenario(**kw)
    rec, _ = simulate(sc, seed=3)
    rig = rig_of(sc)
    kept, found = prepare(rec, rig)
    assert found["orientation"]["applied"] == [] and found["swaps"] == []
    assert found["excluded"] == [] and found["sigma_notes"] == []
    assert kept == rec
    lugs = [m for m, r in zip(rec.markers, rec.roles) if r == "lug"]
    t_mid = float(np.median(np.unique(rec.t)))
    bad = _swap(rec.with_(x=-rec.x), lugs[0], lugs[1], t_mid)
    kept2, found2 = prepare(bad, rig)
    assert kept2 == kept.with_(x=kept.x)
    assert found2["orientation"]["direction"] == "-x" and len(found2["swaps"]) == 1


# -- sigma_mm: holes and absurd values -------------------------------------------------------

def test_sigma_column_holes_and_an_absurd_marker_are_handled(ref):
    from fitlug.fit import build_problem

    rig = read_rig(os.path.join(REF_DIR, "rig.toml"))
    true_lug = 0.0065  # the reference recording's lug noise (truth.json's simulation)
    sigma = np.where(np.isin(ref.marker_index, ref.markers_of("lug")), true_lug, 0.0041)
    b03 = ref.marker_index == ref.markers.index("B03")
    absurd = ref.with_(sigma=np.where(b03, 1e-9, sigma))
    with pytest.warns(UserWarning, match="sigma_mm of marker.*B03 .*replaced by the measured"):
        prob = build_problem(absurd, rig)
    w = np.asarray(prob.obs["lug_w"])[np.isin(prob.lug_rows, np.flatnonzero(b03))]
    assert 0.8 / true_lug < float(np.median(w)) < 1.25 / true_lug
    holes = sigma.copy()
    holes[np.flatnonzero(b03)[::50]] = np.nan
    with pytest.warns(UserWarning, match="sigma_mm is empty in 13 valid sample.*B03.*filled"):
        prob = build_problem(ref.with_(sigma=holes), rig)
    assert prob.noise_source == "sigma_mm column"
    np.testing.assert_allclose(np.asarray(prob.obs["lug_w"]), 1 / true_lug)


# -- the whole run: every fault at once gives the clean twin's answer --------------------------

def test_faulty_recording_gives_its_clean_twins_answer_and_lists_what_was_found(tmp_path):
    """Driving towards -x with y pointing down, B01 and B02 swapping ids from frame 300, a
    3-frame reflection tracked as lug B99 and a static reflection labelled body for 1 s:
    today's main printed k and C_rr negative (or did not converge) and a slip off by
    many sigma; the answer must be the clean recording's (the issue's figures)."""
    from fitlug.cli import main

    ref = read_trajectories(REF)
    bad = _swap(ref, "B01", "B02", 3.0)
    bad = _add(bad, "B99", "lug", [3.0, 3.01, 3.02], 300.0, 40.0)
    bad = _add(bad, "C9", "body", np.arange(200, 300) / 100, 250.0, 70.0)
    bad = bad.with_(x=-bad.x, y=-bad.y)
    folder = tmp_path / "day"
    folder.mkdir()
    write_trajectories(folder / "trajectories.csv", bad)
    (folder / "rig.toml").write_text(open(os.path.join(REF_DIR, "rig.toml")).read())
    out = tmp_path / "out"
    out.mkdir()
    for stale in ("report.html", "state.npz", "posterior.nc"):  # an earlier run's set
        (out / stale).write_text("old")
    assert main([str(folder / "trajectories.csv"), "--no-mcmc", "--no-explain",
                 "--no-report", "-q", "--out", str(out)]) == 0
    assert sorted(os.listdir(out)) == ["fit.json"]  # no file of the earlier run is left
    doc = json.loads((out / "fit.json").read_text())
    assert abs(doc["slip"]["value"] - 0.0771578) < 1e-6  # the clean recording's answer
    assert doc["slip"]["std"] == pytest.approx(2.1e-6, rel=0.05)
    assert doc["stiffness_N_per_mm"]["value"] == pytest.approx(0.2502, abs=2e-4)
    assert doc["rolling_resistance"]["value"] == pytest.approx(0.1000, abs=1e-4)
    assert doc["chi2_per_dof"] < 1.1
    assert doc["direction"] == "-x" and doc["orientation"]["y_axis"] == "down"
    assert [(s["markers"], s["t_s"]) for s in doc["swaps"]] == [(["B01", "B02"], 3.0)]
    assert sorted(x["marker"] for x in doc["excluded"]) == ["B99", "C9"]
    assert len(doc["run_id"]) == 12


# -- output folders --------------------------------------------------------------------------

def test_output_folder_lock(tmp_path):
    from fitlug.cli._outdir import LOCK, locked

    with locked(str(tmp_path), "run1"):
        assert (tmp_path / LOCK).exists()
        with pytest.raises(InputError, match="is in use by another fit-lug run"):
            with locked(str(tmp_path), "run2"):
                pass
    assert not (tmp_path / LOCK).exists()
    # a lock left by a run that is gone is taken over
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    import socket

    (tmp_path / LOCK).write_text(json.dumps({"pid": gone.pid, "host": socket.gethostname()}))
    with locked(str(tmp_path), "run3"):
        assert json.loads((tmp_path / LOCK).read_text())["run_id"] == "run3"


def test_default_output_folders_do_not_collide(tmp_path, monkeypatch):
    from fitlug.cli._common import recording_name
    from fitlug.cli._outdir import default_folder

    monkeypatch.chdir(tmp_path)
    a = str(tmp_path / "day1" / "run1" / "trajectories.csv")
    b = str(tmp_path / "day2" / "run1" / "trajectories.csv")
    assert default_folder(a, recording_name(a)) == os.path.join("fits", "run1")
    os.makedirs("fits/run1")
    with open("fits/run1/fit.json", "w") as fh:
        json.dump({"input": a, "input_abs": a}, fh)
    assert default_folder(a, recording_name(a)) == os.path.join("fits", "run1")  # a rerun
    assert default_folder(b, recording_name(b)) == os.path.join("fits", "day2-run1")


def test_report_refuses_a_folder_mixing_two_runs(tmp_path):
    from fitlug.report import write_report

    (tmp_path / "fit.json").write_text(json.dumps({"run_id": "aaaaaaaaaaaa"}))
    np.savez(tmp_path / "state.npz", meta=np.array(json.dumps({"run_id": "bbbbbbbbbbbb"})))
    with pytest.raises(InputError, match="fit.json \\(run aaaaaaaaaaaa\\) and state.npz "
                                         "\\(run bbbbbbbbbbbb\\) come from different runs"):
        write_report(tmp_path)


# -- fit-lug noise on a moving robot ---------------------------------------------------------

def test_noise_of_a_moving_robot_is_refused_not_reported():
    from types import SimpleNamespace

    from fitlug.vision import noise_from_tracks

    rng = np.random.default_rng(0)
    n = 100
    still = rng.normal(0, 0.05, (n, 2, 2)) + np.array([[100.0, 50.0], [300.0, 60.0]])
    res = SimpleNamespace(xy_px=still, markers=["m0", "m1"], roles=["body", "lug"],
                          kinds=["qs", "cog"], frames=np.arange(n))
    noise = noise_from_tracks(res)  # a stationary robot: the spread is the noise (0.05 px)
    assert noise.per_role["body"]["std_px"] == pytest.approx(0.05, rel=0.25)
    moving = still.copy()
    moving[:, 1, 0] += 1.5 * np.arange(n)  # the lug marker drives by at 1.5 px a frame
    res.xy_px = moving
    with pytest.raises(InputError, match="marker m1 moves during the recording"):
        noise_from_tracks(res)

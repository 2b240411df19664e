"""The command line: a thin layer that writes complete files or none, and one-line errors."""

import json
import os
import subprocess
import sys

import pytest

from fitlug.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REF = os.path.join(ROOT, "data", "reference", "trajectories.csv")


def test_version_and_help(capsys):
    assert main(["--version"]) == 0
    assert "fitlug" in capsys.readouterr().out
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for sub in ("simulate", "report", "track", "calibrate", "noise"):
        assert sub in out
    with pytest.raises(SystemExit) as e:
        main(["fit", "--help"])
    assert e.value.code == 0


def test_fit_reference_least_squares_only(tmp_path, capsys):
    out = tmp_path / "fit"
    assert main([REF, "--no-mcmc", "--no-explain", "--no-report", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "slip" in printed and "chi2/dof" in printed
    doc = json.loads((out / "fit.json").read_text())
    with open(os.path.join(ROOT, "data", "reference", "truth.json")) as fh:
        truth = json.load(fh)
    for key in ("input", "slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance",
                "geometry", "noise_mm", "chi2_per_dof"):
        assert key in doc, key
    assert doc["mcmc"] is None and "mcmc_skipped" in doc
    s = doc["slip"]
    assert abs(s["value"] - truth["slip"]) <= 3 * s["std"]
    assert s["ci95"][0] < truth["slip"] < s["ci95"][1]
    assert set(doc["geometry"]) >= {"R_mm", "D_mm", "e_mm", "pitch_mm"}


def test_quiet_prints_nothing(tmp_path, capsys):
    assert main([REF, "--no-mcmc", "--no-explain", "--no-report", "-q",
                 "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out == ""


def test_bad_input_one_line_error_and_no_output(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,marker,role,x_mm,y_mm\n0.0,C1,body,1.0,2.0\n0.01,C1,wheel,1,2\n")
    before = bad.read_bytes()
    out = tmp_path / "out"
    assert main([str(bad), "--no-mcmc", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.csv:3" in err and "wheel" in err
    assert not (out / "fit.json").exists()
    assert bad.read_bytes() == before  # inputs are never modified
    assert main([str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    assert "missing.csv" in capsys.readouterr().err


def test_simulate_writes_a_recording(tmp_path, capsys):
    d = tmp_path / "sim"
    assert main(["simulate", str(d), "--seed", "3", "--duration", "2.5",
                 "--effect", "belt_sag:sag_d=0.5", "-q"]) == 0
    for f in ("trajectories.csv", "rig.toml", "truth.json"):
        assert (d / f).exists()
    truth = json.loads((d / "truth.json").read_text())
    assert truth["effects"] == {"belt_sag": {"sag_d": 0.5}}
    from fitlug.sim import Scenario  # --duration stretches the profile: same cruise speed
    assert truth["profile"]["duration_s"] == 2.5
    assert truth["profile"]["v_cruise_mm_s"] == pytest.approx(Scenario().v_cruise)
    assert main(["simulate", str(tmp_path / "x"), "--effect", "belt_sag:d=1"]) == 2
    assert "sag_d" in capsys.readouterr().err


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "fitlug.cli", "--version"], capture_output=True,
                       text=True, check=True)
    assert r.stdout.startswith("fitlug ")


def test_out_naming_an_existing_file_is_refused_before_fitting(tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.write_text("keep me")
    for out, problem in ((taken, "is an existing file, not a folder"),
                         (taken / "sub", "cannot be created")):
        assert main([REF, "--no-mcmc", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("fit-lug: error: --out: ")
        assert problem in err
    assert taken.read_text() == "keep me"


@pytest.mark.parametrize("options,problem", [
    (["--duration", "-1"], "--duration: must be a number > 0, got -1.0"),
    (["--duration", "0"], "--duration: must be a number > 0"),
    (["--duration", "0.05"], "--duration: 0.05 s at 100 fps gives 5 frames"),
    (["--fps", "0"], "--fps: must be a number > 0"),
    (["--fps", "-5"], "--fps: must be a number > 0, got -5.0"),
    (["--fps", "inf"], "--fps: must be a number > 0, got inf"),
    (["--slip", "nan"], "--slip: must be a number between 0 and 1"),
    (["--slip", "1"], "--slip: must be a number between 0 and 1"),
    (["--slip", "-0.1"], "--slip: must be a number between 0 and 1"),
    (["--effect", "wheel_runout"], "every parameter of wheel_runout is at its identity value "
                                   "(runout_a=0, runout_b=0)"),
    (["--effect", "belt_sag:sag_d=nan"], "sag_d must be a finite number"),
    (["--effect", "warp_drive:x=1"], "unknown effect 'warp_drive'"),
    (["--scenario", '{"n_belt": 2}'], "not a valid scenario: n_belt"),
    (["--scenario", '{"lug_markers": 0}'], "not a valid scenario: lug_markers"),
])
def test_simulate_refuses_useless_options(tmp_path, capsys, options, problem):
    out = tmp_path / "sim"
    assert main(["simulate", str(out), "-q", *options]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and problem in err
    assert not out.exists()


def test_simulate_help_lists_the_effects_and_their_parameters(capsys):
    from fitlug.model.effects import CATALOG
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    lines = capsys.readouterr().out.splitlines()
    for eid, cls in CATALOG.items():
        i = next(i for i, x in enumerate(lines) if x.strip().startswith(eid + " "))
        # fit.json's names: what the report of a non-identity effect holds
        reported = cls.report({k: 0.5 for k in cls.defaults})
        assert lines[i].split("fit.json:")[1].strip().split(", ") == list(reported)
        for param in cls.defaults:
            assert param + "=" in lines[i + 1], (eid, param)


@pytest.mark.parametrize("eid", ["lug_ripple", "wheel_runout", "body_bounce", "lug_sliding",
                                 "belt_sag", "ground_sinkage", "lens_distortion",
                                 "marker_depth", "camera_tilt", "frame_drop"])
def test_effect_parameters_under_fit_json_names(eid):
    """--effect with fit.json's names reproduces what fit.json would report."""
    import numpy as np

    from fitlug.cli._simulate import parse_effect
    from fitlug.model.effects import CATALOG
    cls = CATALOG[eid]
    rng = np.random.default_rng(5)
    p = {k: float(abs(cls.scales.get(k, 1.0)) * rng.uniform(0.5, 2.0)) for k in cls.defaults}
    reported = cls.report(p)
    given = {k: v for k, v in reported.items() if v is not None and k != "inv_s_K"}
    if eid == "marker_depth":  # its centre is not reported: give it by the model's names
        given.update(depth_cx=p["depth_cx"], depth_cy=p["depth_cy"])
    text = eid + ":" + ",".join(f"{k}={v!r}" for k, v in given.items())
    _, model = parse_effect(text)
    again = cls.report({**cls.defaults, **model})
    for k, v in reported.items():
        assert again[k] == pytest.approx(v, rel=1e-12, abs=1e-15), (k, text)


def _ref_parts():
    with open(REF) as fh:
        lines = fh.read().splitlines()
    n_meta = sum(1 for line in lines if line.startswith("#"))
    return lines[:n_meta], lines[n_meta], lines[n_meta + 1:]


def _frozen(rows):
    """Every marker held at its first position (plus the file's own noise): no motion."""
    first, out = {}, []
    for row in rows:
        f = row.split(",")
        x, y = first.setdefault(f[1], (float(f[3]), float(f[4])))
        noise = (hash(row) % 1000 - 500) * 1e-5
        out.append(",".join(f[:3] + [repr(x + noise), repr(y - noise)] + f[5:]))
    return out


def _case(kind):
    meta, header, rows = _ref_parts()
    rig = "[track]\nload_bearing_length_mm = 127.0\nlugs_in_contact = 8\n[camera]\nfps = 100\n"
    if kind == "rig_1e300":
        rig = rig.replace("127.0", "1e300")
    elif kind == "rig_fps":
        rig = rig.replace("fps = 100", "fps = 120")
    elif kind == "meta_fps":
        meta = ["# fps: 25"] + meta[1:]
    elif kind == "semicolons":
        header, rows = header.replace(",", ";"), [r.replace(",", ";") for r in rows]
    elif kind == "frame_1e19":
        rows[100] = ",".join(rows[100].split(",")[:5] + ["1e19"])
    elif kind == "far_off":
        rows[-1] = ",".join(["649.0"] + rows[-1].split(",")[1:])
    elif kind == "still":
        rows = _frozen(rows)
    elif kind == "metres":
        rows = [",".join(f[:3] + [repr(float(f[3]) / 1000), repr(float(f[4]) / 1000)] + f[5:])
                for f in (r.split(",") for r in rows)]
    return "\n".join(meta + [header] + rows) + "\n", rig


@pytest.mark.parametrize("kind,where,problem", [
    ("rig_1e300", "rig.toml:2", "load_bearing_length_mm = 1e+300 mm is outside the plausible"),
    ("rig_fps", "rig.toml", "[camera] fps 120 disagrees with the time stamps"),
    ("meta_fps", "trajectories.csv:1", "metadata fps 25 disagrees with the time stamps"),
    ("semicolons", "trajectories.csv:4", "the separator looks wrong: ';'"),
    ("frame_1e19", "trajectories.csv:105", "frame number 1e19 is out of range"),
    ("far_off", "trajectories.csv:7804", "time_s = 649.0 breaks the frame rate"),
    ("still", "trajectories.csv", "the robot never moves"),
    ("metres", "trajectories.csv", "look like metres"),
])
def test_bad_recordings_get_one_line_and_no_output(tmp_path, capsys, kind, where, problem):
    text, rig = _case(kind)
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "trajectories.csv").write_text(text)
    (folder / "rig.toml").write_text(rig)
    out = tmp_path / "out"
    assert main([str(folder / "trajectories.csv"), "--no-mcmc", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert err.startswith(f"fit-lug: error: {folder}/{where}: "), err
    assert problem in err
    assert not out.exists()
    assert (folder / "trajectories.csv").read_text() == text  # inputs never modified


def test_progress_lines_and_the_compile_notice_only_when_compiling(tmp_path, capsys,
                                                                     monkeypatch):
    """Issue 43 item 5: the sampler's steps and ESS so far, each line with its stage's
    elapsed seconds; no compile notice on a run that compiles nothing."""
    from fitlug.cli import _common

    monkeypatch.setattr(_common, "PROGRESS_EVERY_S", 0.0)  # every record a line
    args = [REF, "--no-report", "--seed", "2"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0  # compiles what it must
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "b")]) == 0  # the same shapes: nothing new
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("[sampling] ") and "steps" in ln]
    assert lines and all(ln.endswith(" s)") and "ESS" in ln for ln in lines)
    assert lines[-1].split(" (")[-2].endswith("converged")
    assert "compiling" not in out
    assert "first run compiles" not in out


def test_compile_watch_sees_real_compiles_only():
    """A real compile is seen once, a call served from memory not at all. In a process of
    its own: a CI worker's earlier tests leave cache-hit counts behind (seen there: [])."""
    script = """
import jax, jax.numpy as jnp
from fitlug import _progress
seen = []
x = jnp.ones(7).block_until_ready()
jax.config.update("jax_enable_compilation_cache", False)  # a real compile
_progress.watch_compiles(lambda name, s: seen.append(name))
f = jax.jit(lambda x: jnp.sin(x) * 3.25 + 0.125)
f(x).block_until_ready()
first = list(seen)
f(x).block_until_ready()  # in memory: no compile at all
print(first, seen)
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[-2] == "['jit(<lambda>)'] ['jit(<lambda>)']", r.stdout


def test_third_party_warnings_stay_off_the_terminal(capsys, monkeypatch):
    import fitlug
    from fitlug.cli import _show_warning

    monkeypatch.delenv("FITLUG_WARNINGS", raising=False)
    _show_warning(FutureWarning("ArviZ is undergoing a major refactor"), FutureWarning,
                  "/somewhere/site-packages/arviz/__init__.py", 50)
    assert capsys.readouterr().err == ""
    ours = os.path.join(os.path.dirname(fitlug.__file__), "posterior", "_mcmc.py")
    _show_warning(RuntimeWarning("the sampler reached\n its guard"), RuntimeWarning, ours, 9)
    assert capsys.readouterr().err == ("fit-lug: warning: RuntimeWarning: the sampler "
                                       "reached its guard\n")


def test_executable_runs_without_dask_except_campaign():
    """The `fit-lug` executable marks dask unimportable (xarray then does not import it to
    write posterior.nc: ~0.4 s of a warm run, issue 43), except for campaign, which uses
    it; main() called in-process (tests, library callers) leaves it alone."""
    code = ("import sys, atexit; sys.argv = ['fit-lug'] + sys.argv[1:]; import fitlug.cli as c; "
            "atexit.register(lambda: print('DASK', sys.modules.get('dask', 'absent') is None)); "
            "c.entry()")
    for args, blocked in ((["--version"], True), (["campaign", "--help"], False)):
        r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                           timeout=120)
        assert f"DASK {blocked}" in r.stdout, (args, r.stdout[-300:], r.stderr[-300:])
    from fitlug import cli

    assert cli.main(["--version"]) == 0
    assert sys.modules.get("dask", "absent") is not None


def test_a_slip_law_that_cannot_be_sampled_still_writes_the_fit(tmp_path, capsys, monkeypatch):
    """An engine crawler whose lug tips slide ended `fit-lug` with "the data do not
    constrain the slip law (s0, beta): its marginal information matrix is singular" after
    two minutes of fitting and explaining, and wrote nothing. Where the slip law's marginal
    cannot be formed the fit and its explanation are still written; no error bar of the law
    is promised (the slip's included: each says why), and fit.json says why there is no
    posterior."""
    import fitlug.posterior as posterior
    from fitlug import FitError

    why = ("the data do not constrain the slip law (s0, beta): its marginal information "
           "matrix is singular")

    def singular(*a, **k):
        raise FitError(why)

    monkeypatch.setattr(posterior, "sample_posterior", singular)
    monkeypatch.setattr(posterior, "least_squares_identifiability", singular)
    out = tmp_path / "fit"
    assert main([REF, "--no-explain", "--no-report", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "no posterior: " + why in printed
    doc = json.loads((out / "fit.json").read_text())
    assert doc["mcmc"] is None and doc["mcmc_skipped"].startswith(why)
    for key in ("slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance"):
        assert doc[key] is None and doc["not_identifiable"][key] == why, key
    assert "slip s0            not identifiable: " + why in printed
    assert doc["chi2_per_dof"] < 1.5 and doc["geometry"]["R_mm"] > 0  # the fit is written
    # the report's headline says why for the slip too (it showed a bare dash)
    from fitlug.report._section_summary import _headline

    html = _headline(doc, {"meta": {}})
    first = html.split("</tr>")[0]
    assert "slippage" in first and "not identifiable: " + why in first
    # and why no posterior, once (mcmc_skipped names the errors' method already)
    assert f"Posterior not sampled ({why}: uncertainties are " in html.replace("&#x27;", "'")
    assert "the errors are the least-squares (Jacobian) ones" not in html

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
    assert main(["simulate", str(d), "--seed", "3", "--duration", "2",
                 "--effect", "belt_sag:sag_d=0.5", "-q"]) == 0
    for f in ("trajectories.csv", "rig.toml", "truth.json"):
        assert (d / f).exists()
    truth = json.loads((d / "truth.json").read_text())
    assert truth["effects"] == {"belt_sag": {"sag_d": 0.5}}
    assert main(["simulate", str(tmp_path / "x"), "--effect", "belt_sag:d=1"]) == 2
    assert "sag_d" in capsys.readouterr().err


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "fitlug.cli", "--version"], capture_output=True,
                       text=True, check=True)
    assert r.stdout.startswith("fitlug ")

"""The report drawn by a process of its own (fitlug.report._aside, the `fit-lug`
executable's way): the same page as drawn in the fitting process, its early parts (drawn
while the posterior is sampled) the same as drawn from the final files, a failing child
replaced by the calling process, and nothing left behind."""

from __future__ import annotations

import json
import os
import shutil
import sys
import threading

import pytest

from fitlug import InputError
from fitlug.cli import _fit as cli_fit
from fitlug.cli import main
from fitlug.report import write_report
from fitlug.report._aside import ReportProcess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REFERENCE = os.path.join(ROOT, "fits", "reference")


def _scratch_folders():
    import tempfile

    return {n for n in os.listdir(tempfile.gettempdir()) if n.startswith("fitlug-report-")}


def _read(path):
    with open(path, "rb") as fh:
        return fh.read()


def test_child_draws_the_page_the_caller_would(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(REFERENCE, a)
    shutil.copytree(REFERENCE, b)
    os.remove(a / "report.html")
    rp = ReportProcess()
    child = rp.proc
    assert rp.render(a) == str(a / "report.html")
    assert {k: rp.answer[k] for k in ("path", "early")} == {"path": str(a / "report.html"),
                                                            "early": "none"}
    rp = ReportProcess()  # a relative folder: the path comes back as the caller gave it
    monkeypatch.chdir(tmp_path)
    assert rp.render("a") == os.path.join("a", "report.html")
    assert child.poll() is not None and rp.proc is None  # the child is gone
    write_report(b)
    assert _read(a / "report.html") == _read(b / "report.html")


def test_a_failing_child_is_replaced_by_the_caller(tmp_path):
    """A folder without state.npz: the child fails, the caller draws the page and raises
    the rendering's own one-line error; a child that was never used is stopped."""
    shutil.copytree(REFERENCE, tmp_path / "f")
    os.remove(tmp_path / "f" / "state.npz")
    rp = ReportProcess()
    with pytest.raises(InputError, match="state.npz"):
        rp.render(tmp_path / "f")
    assert "error" in rp.answer and "InputError" in rp.answer["error"]
    rp = ReportProcess()
    child = rp.proc
    rp.close()
    assert child.poll() is not None
    # a child killed before it answers (out of memory, a signal): the caller draws the page
    shutil.copytree(REFERENCE, tmp_path / "g")
    os.remove(tmp_path / "g" / "report.html")
    rp = ReportProcess()
    rp.proc.kill()
    rp.proc.wait()
    assert rp.render(tmp_path / "g") == str(tmp_path / "g" / "report.html")
    assert rp.answer is None and _read(tmp_path / "g" / "report.html").startswith(b"<!DOCTYPE")


def test_executable_run_draws_early_parts_and_the_same_page(tmp_path, monkeypatch, capsys):
    """The whole default run as the executable makes it (REPORT_PROCESS): the early parts
    were used (the final files agree with their inputs), and the page equals the one the
    fitting process draws from the final files alone, byte for byte."""
    answers = []
    render = ReportProcess.render

    def spy(self, out_dir):
        path = render(self, out_dir)
        answers.append(self.answer)
        return path

    monkeypatch.setattr(ReportProcess, "render", spy)
    monkeypatch.setattr(cli_fit, "REPORT_PROCESS", True)
    before = _scratch_folders()
    out = tmp_path / "out"
    assert main([os.path.join(ROOT, "data", "reference", "trajectories.csv"), "--out",
                 str(out), "-q"]) == 0
    assert answers and answers[0]["early"] == "used", answers
    if sys.platform.startswith("linux"):  # drawn by forked copies of the report process
        assert {"convergence", "trajectories", "residuals"} <= set(answers[0]["copies"])
    assert sorted(os.listdir(out)) == ["fit.json", "posterior.nc", "report.html", "state.npz"]
    assert _scratch_folders() == before  # the early parts' scratch folder removed
    again = tmp_path / "again"
    shutil.copytree(out, again)
    os.remove(again / "report.html")
    write_report(again)
    page = _read(out / "report.html")
    assert page == _read(again / "report.html")
    assert page.count(b"<img ") >= 12  # the early sections' and the discrepancy's figures


def test_when_the_report_gets_a_process_of_its_own(monkeypatch):
    """Only in the executable, for a recording of at most 200 000 samples, and not with
    FITLUG_REPORT_PROCESS=0."""
    import numpy as np

    from fitlug.io import Recording

    def rec(n):
        return Recording(markers=("1",), roles=("lug",), t=np.arange(n) / 100.0,
                         marker_index=np.zeros(n, int), x=np.zeros(n), y=np.zeros(n))

    small, big = rec(1000), rec(cli_fit.REPORT_PROCESS_MAX_SAMPLES + 1)
    monkeypatch.delenv("FITLUG_REPORT_PROCESS", raising=False)
    assert not cli_fit._report_process(small)  # main() called in-process
    monkeypatch.setattr(cli_fit, "REPORT_PROCESS", True)
    assert cli_fit._report_process(small) and not cli_fit._report_process(big)
    monkeypatch.setenv("FITLUG_REPORT_PROCESS", "0")
    assert not cli_fit._report_process(small)


def test_the_child_imports_the_callers_fitlug(monkeypatch):
    """A source tree the caller imported fitlug from goes first on the child's PYTHONPATH;
    an installed fitlug's site folder does not (it would go before the standard library)."""
    import subprocess

    import fitlug
    from fitlug.report import _aside

    root = os.path.dirname(os.path.dirname(os.path.abspath(fitlug.__file__)))
    seen = []

    class FakePopen:
        def __init__(self, cmd, env=None, **kw):
            seen.append(env)

    monkeypatch.setattr(subprocess, "Popen", FakePopen)
    monkeypatch.setenv("PYTHONPATH", "/elsewhere")
    monkeypatch.setattr(_aside, "_site_folders", lambda: set())
    ReportProcess()
    assert seen[-1]["PYTHONPATH"] == os.pathsep.join([root, "/elsewhere"])
    monkeypatch.setattr(_aside, "_site_folders", lambda: {root})
    ReportProcess()
    assert seen[-1]["PYTHONPATH"] == "/elsewhere"


def _pipe_source(keys, parts=None, release=None):
    """A _Forked whose 'copy' is a thread writing `parts` (None: nothing, a failed copy)
    into its pipe once `release` is set."""
    from fitlug.report._aside import _Forked

    r, w = os.pipe()

    def write():
        if release is not None:
            release.wait(30)
        with os.fdopen(w, "wb") as fh:
            if parts is not None:
                fh.write(json.dumps({"parts": parts, "peak_rss_bytes": 1}).encode())

    threading.Thread(target=write, daemon=True).start()
    return _Forked(r, None, keys)


def test_parts_wait_only_for_the_copy_that_draws_them():
    from fitlug.report._aside import _Parts

    release = threading.Event()
    early = _pipe_source(("trajectories",), {"trajectories": "<p>T</p>"}, release)
    conv = _pipe_source(("convergence",), {"convergence": "<p>C</p>"})
    parts = _Parts([early, conv])
    got = {}
    t = threading.Thread(target=lambda: got.update(c=parts["convergence"]), daemon=True)
    t.start()
    t.join(10)
    assert got == {"c": "<p>C</p>"}  # the early copy is still drawing
    release.set()
    assert "trajectories" in parts and parts["trajectories"] == "<p>T</p>"
    assert "residuals" not in parts and sorted(parts) == ["convergence", "trajectories"]


def test_a_failed_copy_leaves_its_parts_to_the_page(tmp_path):
    """A copy that hands back nothing: the page draws those parts itself, the same page."""
    from fitlug.report._aside import _Parts
    from fitlug.report._page import EARLY

    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(REFERENCE, a)
    shutil.copytree(REFERENCE, b)
    failed = _pipe_source(EARLY + ("convergence",), None)
    parts = _Parts([failed])
    assert "convergence" not in parts and not failed.drawn
    write_report(a, parts)
    write_report(b)
    assert _read(a / "report.html") == _read(b / "report.html")


def test_a_copy_that_hangs_is_ended_and_its_parts_left_to_the_page(monkeypatch):
    from fitlug.report import _copies

    monkeypatch.setattr(_copies, "WAIT_S", 0.5)
    r, w = os.pipe()  # a copy that never writes nor ends
    try:
        hung = _copies._Forked(r, None, ("trajectories",))
        parts = _copies._Parts([hung])
        assert "trajectories" not in parts and not hung.drawn
    finally:
        os.close(w)

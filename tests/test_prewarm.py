"""fitlug.cli._prewarm and fitlug._exported's threads: on a first run the later stages'
programs are compiled by a thread beside the solver's, with the shapes the stages then
use, and the answers are those of programs read back from disk; a program two threads
ask for at once is exported and compiled once."""

from __future__ import annotations

import json
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlug import _exported
from fitlug.cli import _fit as cli_fit
from fitlug.cli import _prewarm, main
from fitlug.sim import Scenario, simulate, write_simulation


@pytest.fixture
def fresh_disk(tmp_path, monkeypatch):
    """An empty module folder and no module held in this process: a first run's exports."""
    monkeypatch.setattr(_exported, "cache_dir", lambda: str(tmp_path / "exported"))
    monkeypatch.setattr(_exported, "_MEMO", {})
    monkeypatch.setattr(_exported, "_READY", set())
    monkeypatch.setattr(_exported, "FIRST_CALLER", {})
    return tmp_path


def _program(x, y):
    return (jnp.sin(x) @ y + 1.0,)


def test_two_threads_asking_for_one_new_program_export_and_compile_it_once(
        fresh_disk, monkeypatch):
    exports, hooks = [], []
    real = jax.export.export

    def counting(*a, **k):
        exports.append(threading.current_thread().name)
        return real(*a, **k)

    monkeypatch.setattr(jax.export, "export", counting)
    _exported.on_export(hooks.append)
    try:
        x, y = np.linspace(0, 1, 7), np.ones((7, 3))
        gate, out = threading.Barrier(2), {}

        def ask(tag):
            gate.wait()
            out[tag] = _exported.call("two_threads", _program, (), x, y)

        threads = [threading.Thread(target=ask, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        _exported.remove_on_export(hooks.append)
    assert len(exports) == 1 and hooks == ["two_threads"]
    want = np.sin(x) @ y + 1.0
    for tag in (0, 1):
        np.testing.assert_allclose(np.asarray(out[tag][0]), want, rtol=1e-14)
    # read back, the next process (memo emptied) neither exports nor calls the hook
    monkeypatch.setattr(_exported, "_MEMO", {})
    monkeypatch.setattr(_exported, "_READY", set())
    _exported.on_export(hooks.append)
    try:
        again = _exported.call("two_threads", _program, (), x, y)
    finally:
        _exported.remove_on_export(hooks.append)
    assert len(exports) == 1 and hooks == ["two_threads"]
    np.testing.assert_array_equal(np.asarray(again[0]), np.asarray(out[0][0]))


def test_first_run_compiles_the_later_stages_programs_in_the_thread(fresh_disk, monkeypatch):
    """A default run (posterior and report) whose solver module is exported afresh: the
    thread starts, every program it makes is one the stages then call with the same
    shapes, and the numbers equal those of a later run whose programs are read back."""
    sc = Scenario(duration_s=2.0, travel_mm=200, rest_s=0.2, ramp_s=0.5)
    rec_dir = fresh_disk / "rec"
    write_simulation(str(rec_dir), sc, seed=11)
    csv = str(rec_dir / "trajectories.csv")
    calls = []
    real_call = _exported.call

    def spy(name, fn, static, *args):
        leaves = jax.tree_util.tree_leaves(args)
        sig = (name, repr(static), tuple((np.shape(x), str(np.asarray(x).dtype))
                                         for x in leaves))
        who = threading.current_thread().name
        calls.append(("fitlug-prewarm" if who.startswith("fitlug-prewarm") else who, sig))
        return real_call(name, fn, static, *args)

    monkeypatch.setattr(_exported, "call", spy)
    monkeypatch.setattr(cli_fit, "PREWARM", True)
    first = fresh_disk / "first"
    assert main([csv, "--out", str(first), "-q"]) == 0
    _prewarm.join(120)
    ahead = {sig for who, sig in calls if who == "fitlug-prewarm"}
    used = {sig for who, sig in calls if who == "MainThread"}
    names = {sig[0] for sig in ahead}
    # the stages' programs after the solver's: each one the thread made, a stage used
    assert {"derived", "glitch_predict", "kinematics_segments", "posterior_jacobian",
            "posterior_project", "posterior_chi2"} <= names, names
    assert ahead <= used, sorted(s[0] for s in ahead - used)
    assert "fitlug-prewarm" in set(_exported.FIRST_CALLER.values())
    # as the next process: every module read back from disk, no thread
    monkeypatch.setattr(_exported, "_MEMO", {})
    monkeypatch.setattr(_exported, "_READY", set())
    n_threads = len(_prewarm._THREADS)
    second = fresh_disk / "second"
    assert main([csv, "--out", str(second), "-q", "--no-report"]) == 0
    assert len(_prewarm._THREADS) == n_threads
    a, b = (json.loads((d / "fit.json").read_text()) for d in (first, second))
    assert a["slip"] == b["slip"]
    assert a["mcmc"]["steps"] == b["mcmc"]["steps"]

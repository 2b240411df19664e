"""Strict test environment: float64 JAX, a private compile cache, helpers on sys.path."""

import os
import sys

os.environ.setdefault("FITLUG_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache",
                                                        "fitlug", "jax-tests"))
sys.path.insert(0, os.path.dirname(__file__))

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


# --- scheduling on the CI's two workers (issue 43, item 6) ---------------------------------
# `--dist loadgroup` (pyproject). A test that reads a module-scoped fixture goes in its
# file's xdist group, so that the fixture is built once, on one worker; every other test is
# a group of its own, which xdist hands to whichever worker is free (a file of independent
# minute-long tests, test_straight_runs' engine recordings or test_families' mechanisms,
# was one unit of up to a third of the run on one worker). The heaviest files' tests are
# queued first, so that the last to finish is short.
#: the files' wall seconds cold (2026-12-02, FITLUG_PROFILE_COMPILES, benchmarks/
#: ci_profile.py), for the order only; files not named come after them, in collection order
FILE_COST = {"test_straight_runs.py": 1148, "test_uncertainty.py": 526,
             "test_families.py": 500, "test_drive_through.py": 372,
             "test_families_independent.py": 316, "test_explain_independent.py": 312,
             "test_posterior.py": 250, "test_tracker_error.py": 194, "test_explain.py": 188,
             "test_notebook.py": 188, "test_glitches.py": 163, "test_buckets.py": 161,
             "test_campaign.py": 151, "test_model.py": 147, "test_concealed.py": 94}


def pytest_configure(config):
    # keep the order below: xdist (>= 3.8) otherwise queues the groups by their number of
    # tests, which put the heaviest files (few tests, minutes each) last
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def _shares_a_fixture(item) -> bool:
    """Whether the test reads a fixture built once for its module (or class), or may: one
    that takes `request` can ask for any (request.getfixturevalue: test_uncertainty's
    verdicts read its recordings' fixtures so)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None or "request" in getattr(item, "fixturenames", ()):
        return True
    return any(str(getattr(fd, "scope", "function")) in ("module", "class", "package")
               for defs in info.name2fixturedefs.values() for fd in defs)


# tryfirst: xdist's worker turns a test's xdist_group mark into its group in its own
# pytest_collection_modifyitems, which ran before this one (a plugin registered after the
# conftest): no test had a group, every test was a scope of its own, and a file's tests
# went to both workers, each building the module fixtures (test_uncertainty's five, ~100 s
# CPU) a second time
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    for it in items:
        if _shares_a_fixture(it):
            it.add_marker(pytest.mark.xdist_group(os.path.basename(str(it.fspath))))
    # stable: a file's tests keep their order
    items.sort(key=lambda it: -FILE_COST.get(os.path.basename(str(it.fspath)), 0.0))


# --- where a run's compile time goes (issue 43, item 6) -------------------------------------
# FITLUG_PROFILE_COMPILES=PREFIX writes PREFIX.<worker>.jsonl: per test phase, its wall
# seconds and every jax.monitoring duration (trace, lowering, backend compile, cache reads)
# summed by event; benchmarks/ci_profile.py adds them up by file and by test.
if os.environ.get("FITLUG_PROFILE_COMPILES"):
    import json as _json
    import time as _time

    import jax.monitoring as _mon

    _durations: dict = {}
    _compiled: dict = {}

    def _on_duration(event, seconds, **kwargs):
        _durations[event] = _durations.get(event, 0.0) + float(seconds)
        if event == "/jax/core/compile/backend_compile_duration":
            name = str(kwargs.get("fun_name", ""))
            n, s = _compiled.get(name, (0, 0.0))
            _compiled[name] = (n + 1, s + float(seconds))

    _mon.register_event_duration_secs_listener(_on_duration)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        _durations.clear()
        _compiled.clear()
        t0, c0 = _time.perf_counter(), _time.process_time()
        yield
        rec = {"nodeid": item.nodeid, "wall": _time.perf_counter() - t0,
               "cpu": _time.process_time() - c0, "events": dict(_durations),
               "compiled": dict(_compiled)}
        with open(f"{os.environ['FITLUG_PROFILE_COMPILES']}.{worker}.jsonl", "a") as fh:
            fh.write(_json.dumps(rec) + "\n")

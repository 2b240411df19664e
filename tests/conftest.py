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
# `--dist loadgroup` (pyproject) with one group per file keeps what `--dist loadfile` gave
# (a module fixture is built once), except test_families.py: its cases share no fixture
# and were one file of 837 s CPU (2026-11-28, docs/development.md), longer than the rest
# of one worker's share, so its cases go in FAMILY_GROUPS groups, the heaviest cases in
# different ones. The heaviest groups are queued first, so that the last to finish is short.
FAMILY_GROUPS = 1  # ~100 s cold in the default run (BENCH_IN_CI): one group shares its programs
#: CPU seconds of test_families' cases (2026-11-28 evening, -n 2, user + sys of the worker
#: per test), for the split only; a test without a case here (the unit tests) counts 1
FAMILY_COST = {"rail_bow": 40, "keystone": 35, "squat": 29,
               "speed_hunt": 22, "flap": 21, "carrier_roller": 15, "frame_jitter": 13,
               "frame_vibration": 13, "wheel_runout": 8, "null": 2}
#: the files' wall seconds with a cold JAX cache, their tests in the default run (2026-12-02,
#: benchmarks/ci_profile.py --tier on a full cold run, and a fresh clone's .ci/run: the CI's machine is a fresh
#: one), for the order only; files not named come after them
FILE_COST = {"test_model.py": 139, "test_lug_shear.py": 122, "test_campaign.py": 113,
             "test_posterior.py": 106, "test_fit.py": 96, "test_uncertainty.py": 90,
             "test_straight_runs.py": 70, "test_scale.py": 65, "test_plugins.py": 60,
             "test_explain.py": 60, "test_end_to_end.py": 57, "test_library_api.py": 56,
             "test_cli.py": 54, "test_report.py": 53, "test_explain_independent.py": 50,
             "test_families.py": 100, "test_tracker_error.py": 60, "test_batch.py": 37,
             "test_drive_through.py": 34}


# --- the CI's tier (issue 43, item 6): tests/ci_tier.py ------------------------------
from ci_tier import BENCH_IN_CI  # noqa: E402



def pytest_configure(config):
    # keep the order below: xdist (>= 3.8) otherwise queues the groups by their number of
    # tests, which put the heaviest files (few tests, minutes each) last
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


# tryfirst: xdist's worker turns a test's xdist_group mark into its group in its own
# pytest_collection_modifyitems, which ran before this one (a plugin registered after the
# conftest): no test had a group, every test was a scope of its own, and a file's tests
# went to both workers, each building the module fixtures (test_uncertainty's five, ~100 s
# CPU) a second time
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    for it in items:
        if any(it.nodeid.startswith(k) for k in BENCH_IN_CI):
            it.add_marker(pytest.mark.bench)
    groups = {}
    load = [0.0] * FAMILY_GROUPS
    fam = [it for it in items if os.path.basename(str(it.fspath)) == "test_families.py"]
    # the cases marked bench last: the default run deselects them after this hook (it runs
    # first), so they must not move the others
    for it in sorted(fam, key=lambda i: (i.get_closest_marker("bench") is not None,
                                         -FAMILY_COST.get(_case(i), 1))):
        k = min(range(FAMILY_GROUPS), key=load.__getitem__)
        load[k] += FAMILY_COST.get(_case(it), 1)
        groups[it.nodeid] = (f"test_families.py#{k}", load)
    cost = {}
    for it in items:
        name = os.path.basename(str(it.fspath))
        group = groups.get(it.nodeid, (name,))[0]
        it.add_marker(pytest.mark.xdist_group(group))
        # a family group: its share of the file's cost
        cost[it.nodeid] = (FILE_COST["test_families.py"] * load[int(group[-1])] / sum(load)
                           if "#" in group else FILE_COST.get(name, 0.0))
    items.sort(key=lambda it: -cost[it.nodeid])  # stable: a group's tests keep their order


def _case(item) -> str:
    return item.name.split("[", 1)[1].rstrip("]") if "[" in item.name else ""


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

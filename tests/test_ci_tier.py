"""The CI's tier (tests/conftest.py's BENCH_IN_CI) names tests that exist: a renamed or
mistyped key would otherwise put its test silently back into the default run."""

from __future__ import annotations

import os
import re

from ci_tier import BENCH_IN_CI

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_every_key_names_a_test_function():
    missing = []
    for key, where in BENCH_IN_CI.items():
        path, _, rest = key.partition("::")
        name = rest.split("[", 1)[0]
        src = open(os.path.join(ROOT, path)).read()
        if not re.search(r"^def " + re.escape(name), src, re.M):
            missing.append(key)
        # a case id: the test is parametrized with it (or pytest's own id, argname + index)
        case = rest.split("[", 1)[1].rstrip("]") if "[" in rest else None
        own = re.fullmatch(r"([a-z_]+)\d+", case or "")
        if case is not None and case not in src and not (own and f'"{own[1]}"' in src):
            missing.append(key)
        assert where.strip(), key  # each says where its coverage lives
    assert not missing, missing


def test_no_coverage_is_claimed_by_a_benched_test():
    """Where a key says its check still runs (a test's name), that test is in the tier."""
    whole = {}  # a benched function (every case of it) -> its file
    files = set()
    for key in BENCH_IN_CI:
        path, _, rest = key.partition("::")
        if not rest:
            files.add(path)
        elif "[" not in rest:
            whole[rest] = path
    claimed = []
    for key, where in BENCH_IN_CI.items():
        if "bench" in where:  # "(bench)" or a benchmark script: said to be out of the tier
            continue
        for name in re.findall(r"\btest_\w+", where):
            if os.path.exists(os.path.join(ROOT, "tests", name + ".py")):
                continue  # a file's name: a test of it named beside, or the file's tier
            if any(f.startswith(name) or name.startswith(f) for f in whole):
                claimed.append((key, name))
            for f in files:  # a file benched whole: a test of it named after its name
                path = os.path.join(ROOT, f)
                if re.search(r"^def " + re.escape(name), open(path).read(), re.M):
                    claimed.append((key, name))
    assert not claimed, claimed

"""The CI's tier (tests/conftest.py's BENCH_IN_CI) names tests that exist: a renamed or
mistyped key would otherwise put its test silently back into the default run."""

from __future__ import annotations

import os
import re

from conftest import BENCH_IN_CI

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

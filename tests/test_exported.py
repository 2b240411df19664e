"""fitlug._exported: the solver through a module exported to disk gives the same numbers,
bit for bit, as calling it, whether the module was just exported or read back; anything
unusual falls back to the plain call."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlug import _exported
from fitlug.fit import _lsq
from fitlug.fit._problem import build_problem
from fitlug.sim import Scenario, rig_of, simulate


@pytest.fixture(scope="module")
def solver_args():
    sc = Scenario(duration_s=1.5, travel_mm=150, rest_s=0.2, ramp_s=0.4)
    rec, _ = simulate(sc, 5)
    prob = build_problem(rec, rig_of(sc))
    from fitlug.fit._fit import free_parameters

    packing = _lsq.Packing.of(prob.p0, free_parameters(prob.lay))
    fixed = {k: jnp.asarray(v, float) for k, v in prob.p0.items() if k not in packing.names}
    flat = packing.pack(prob.p0)
    args = (flat, fixed, prob.lay, prob.obs, jnp.ones_like(flat))  # nothing held
    static = (packing, 200, 1e-8, 1e-6)
    return args, static, _lsq._solve(*args, *static)


def _same(a, b):
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b))


def test_exported_solver_equals_the_plain_call_exported_and_read_back(solver_args, tmp_path,
                                                                       monkeypatch):
    args, static, direct = solver_args
    monkeypatch.setattr(_exported, "cache_dir", lambda: str(tmp_path))
    monkeypatch.setattr(_exported, "_MEMO", {})
    stale, recent = tmp_path / "lsq_solve-0ld.jaxexport", tmp_path / "lsq_solve-n3w.jaxexport"
    for f, age_days in ((stale, 40), (recent, 2)):
        f.write_bytes(b"x")
        t = time.time() - age_days * 86400
        os.utime(f, (t, t))
    fresh = _exported.call("lsq_solve", _lsq._solve, static, *args)
    assert not stale.exists() and recent.exists()  # modules unused for 30 days are pruned
    recent.unlink()
    files = os.listdir(tmp_path)
    assert len(files) == 1 and files[0].endswith(".jaxexport")
    assert _same(fresh, direct)
    monkeypatch.setattr(_exported, "_MEMO", {})  # as a new process: read from disk
    monkeypatch.setattr(jax.export, "export", _fail)  # and never exported again
    back = _exported.call("lsq_solve", _lsq._solve, static, *args)
    assert _same(back, direct)


def _fail(*a, **k):
    raise AssertionError("exported again instead of read back")


def test_exported_falls_back_on_a_damaged_file_and_when_disabled(solver_args, tmp_path,
                                                                 monkeypatch):
    args, static, direct = solver_args
    monkeypatch.setattr(_exported, "cache_dir", lambda: str(tmp_path))
    monkeypatch.setattr(_exported, "_MEMO", {})
    _exported.call("lsq_solve", _lsq._solve, static, *args)
    (path,) = [os.path.join(tmp_path, f) for f in os.listdir(tmp_path)]
    with open(path, "wb") as fh:
        fh.write(b"not a module")
    monkeypatch.setattr(_exported, "_MEMO", {})
    assert _same(_exported.call("lsq_solve", _lsq._solve, static, *args), direct)
    assert os.path.getsize(path) > 1000  # exported afresh over the damaged file
    monkeypatch.setenv("FITLUG_NO_EXPORT_CACHE", "1")
    calls = []
    assert _same(_exported.call("x", lambda *a: calls.append(1) or _lsq._solve(*a), static,
                                *args), direct)
    assert calls == [1]


def test_pytree_outputs_exported_and_read_back(solver_args, tmp_path, monkeypatch):
    """Programs whose outputs are dicts go through the disk the same way (the derived
    quantities with their Jacobian, as compute_quantities calls them; the glitch search's
    model evaluation): the same structure and numbers, bit for bit, exported and read
    back."""
    from fitlug.fit._glitches import _predict
    from fitlug.fit._result import _derived_exported

    (flat, fixed, lay, _, _), static, _ = solver_args
    packing = static[0]
    zero = jnp.asarray(0.0, float)
    cases = [("derived", _derived_exported, (packing, False, False), (flat, fixed, lay, zero,
                                                                      zero)),
             ("glitch_predict", _predict, (), (packing.unpack(flat, fixed), lay))]
    monkeypatch.setattr(_exported, "cache_dir", lambda: str(tmp_path))
    for name, fn, st, args in cases:
        direct = fn(*args, *st)
        monkeypatch.setattr(_exported, "_MEMO", {})
        fresh = _exported.call(name, fn, st, *args)
        monkeypatch.setattr(_exported, "_MEMO", {})  # as a new process: read from disk
        back = _exported.call(name, fn, st, *args)
        for out in (fresh, back):
            assert jax.tree_util.tree_structure(out) == jax.tree_util.tree_structure(direct)
            assert all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True) for x, y in
                       zip(jax.tree_util.tree_leaves(out), jax.tree_util.tree_leaves(direct)))
    assert sorted(f.split("-")[0] for f in os.listdir(tmp_path)) == ["derived",
                                                                       "glitch_predict"]


def test_source_identity_follows_contents_not_mtimes(tmp_path):
    """The exported programs' key: a copy of the package with new mtimes (a fresh clone)
    keeps it; an edit of one file, or a new file, changes it."""
    import shutil

    pkg = os.path.dirname(os.path.abspath(_exported.__file__))
    copy = tmp_path / "fitlug"
    shutil.copytree(pkg, copy, ignore=shutil.ignore_patterns("__pycache__"))
    for f in copy.rglob("*.py"):
        os.utime(f, (1e9, 1e9))
    assert _exported._tree_digest(str(copy)) == _exported._tree_digest(pkg)
    target = copy / "fit" / "_lsq.py"
    target.write_text(target.read_text() + "\n# edited\n")
    edited = _exported._tree_digest(str(copy))
    assert edited != _exported._tree_digest(pkg)
    (copy / "extra.py").write_text("x = 1\n")
    assert _exported._tree_digest(str(copy)) not in (edited, _exported._tree_digest(pkg))
    assert _exported._source_identity() == _exported._tree_digest(pkg)  # the key's part

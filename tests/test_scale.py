"""Long recordings: a 5 000-frame recording fits in bounded memory and finds the slip.

The fit runs in a fresh interpreter so that its peak resident memory (VmHWM, which
counts JAX's buffers) is the fit's own; the bound is what the chunked normal equations
need (a dense Jacobian of this recording alone, with its jacfwd intermediates, went past
it before). The truth is the simulator's slip, the error bar the fit's own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")
MEMORY_CAP_BYTES = 1.5 * 1024 ** 3

_CHILD = r"""
import json, resource, sys
import numpy as np


def peak_rss():
    # VmHWM: this process image's own high-water mark. ru_maxrss is not: Linux carries the
    # forked parent's RSS into it at exec, and the parent here is a long pytest run.
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


from fitlug.sim import Scenario, simulate, rig_of
from fitlug.fit import fit
from fitlug.fit import _lsq

sc = Scenario(duration_s=10.0, fps=500.0, travel_mm=1080.0, lug_markers=12, lug_spacing=1)
rec, truth = simulate(sc, seed=3)
before = peak_rss()
calls = []
orig = _lsq._solve_chunked
_lsq._solve_chunked = lambda *a, **k: calls.append(1) or orig(*a, **k)
res = fit(rec, rig_of(sc))
peak = peak_rss()
print(json.dumps({"frames": int(np.unique(rec.frame).size), "markers": len(rec.markers),
                  "slip": res.slip.value, "std": res.slip.std, "truth": truth["slip"],
                  "converged": res.converged, "chi2_per_dof": res.chi2_per_dof,
                  "chunked_calls": len(calls), "peak": peak, "before_fit": before}))
"""


def test_5000_frames_fit_in_bounded_memory_and_find_the_slip():
    env = dict(os.environ)
    env["PYTHONPATH"] = SRC + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                       env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["frames"] == 5000 and out["markers"] == 14
    assert out["chunked_calls"] >= 1  # the long-recording path, not the dense Jacobian
    assert out["converged"] and 0.8 < out["chi2_per_dof"] < 1.2
    assert out["peak"] < MEMORY_CAP_BYTES, f"peak RSS {out['peak'] / 2 ** 20:.0f} MiB"
    assert 0 < out["std"] < 1e-3
    assert abs(out["slip"] - out["truth"]) < 3 * out["std"], out
    assert np.isfinite(out["slip"])


def test_chunked_normal_equations_equal_the_dense_jacobians():
    """J^T J and J^T r from time chunks equal those of the exact dense Jacobian (forward
    mode), with every effect the chunked path takes, a later gauge time, missing samples
    and chunks smaller than a frame interval's window."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from test_model import _small_layout

    from fitlug.fit._lsq import Packing, chunk_plan, chunkable, normal_equations, residuals
    from fitlug.model.effects import CATALOG

    effects = tuple(e for e in CATALOG if e not in ("lug_ripple", "wheel_runout"))
    lay, p = _small_layout(effects)
    lay = dataclasses.replace(lay, t_ref=jnp.asarray(0.137))
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    rng = np.random.default_rng(1)
    obs = {"lug_x": jnp.asarray(rng.normal(size=n_l)), "lug_y": jnp.asarray(rng.normal(size=n_l)),
           "lug_w": jnp.asarray(rng.uniform(50, 200, n_l) * (rng.uniform(size=n_l) > 0.1)),
           "body_x": jnp.asarray(rng.normal(size=n_b)),
           "body_y": jnp.asarray(rng.normal(size=n_b)),
           "body_w": jnp.asarray(rng.uniform(50, 200, n_b))}
    held = {k for e in effects for k in CATALOG[e].fixed_in_fit}
    packing = Packing.of(p, [k for k in p if k not in held])
    fixed = {k: v for k, v in p.items() if k in held}
    flat = packing.pack(p)
    assert chunkable(p, lay, packing)
    J = np.asarray(jax.jacfwd(lambda f: residuals(packing.unpack(f, fixed), lay, obs))(flat))
    r = np.asarray(residuals(p, lay, obs))
    A0, g0 = J.T @ J, J.T @ r
    scale = np.sqrt(np.outer(np.diag(A0), np.diag(A0))) + 1e-12 * np.abs(A0).max()
    for chunk in (7, 50, 10 ** 6):
        A, g, chi2 = normal_equations(flat, fixed, lay, obs, packing, chunk_plan(lay, chunk, 8))
        assert np.max(np.abs(np.asarray(A) - A0) / scale) < 1e-8, chunk
        assert np.max(np.abs(np.asarray(g) - g0)) < 1e-10 * np.max(np.abs(g0)), chunk
        assert abs(float(chi2) - r @ r) < 1e-10 * (r @ r)

"""Long recordings: a 5 000-frame recording fits in bounded memory and finds the slip.

The fit runs in a fresh interpreter so that its peak resident memory (ru_maxrss, which
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
from fitlug.sim import Scenario, simulate, rig_of
from fitlug.fit import fit
from fitlug.fit import _lsq

sc = Scenario(duration_s=10.0, fps=500.0, travel_mm=1080.0, lug_markers=12, lug_spacing=1)
rec, truth = simulate(sc, seed=3)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
calls = []
orig = _lsq._solve_chunked
_lsq._solve_chunked = lambda *a, **k: calls.append(1) or orig(*a, **k)
res = fit(rec, rig_of(sc))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
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

"""Quantities the least squares cannot give as a number: None with the reason.

k = 2 m / (1000 beta n L), k/m, C_rr = s0 / (1000 g beta) and the traction are ratios
over beta = ds/da. Where the data do not fix beta (a cruise-only recording: no
acceleration, so the slip's slope with acceleration is free), its relative standard error
exceeds REL_STD_MAX and a delta-method interval of 1/beta means nothing: the issue saw
k = -2035 ± 1.2e8 N/mm. Such quantities become ``Estimate(None, None, reason=...)`` in
``FitResult.quantities``; the posterior decides the same on its samples
(:mod:`fitlug.posterior._identify`, the same threshold) and its estimates follow suit.
"""

from __future__ import annotations

import math

#: beta's relative std above which quantities nonlinear in it are not identifiable
REL_STD_MAX = 0.25
#: derived quantities that are ratios over beta
OVER_BETA = ("stiffness_N_per_mm", "k_over_m", "rolling_resistance", "traction_N")
_LABEL = {"stiffness_N_per_mm": "k", "k_over_m": "k/m", "rolling_resistance": "C_rr",
          "traction_N": "the traction"}


def mark_not_identifiable(q: dict, estimate) -> dict:
    """`q` (name -> Estimate) with the ratios over beta set to ``estimate(None, None,
    reason=...)`` where beta's relative standard error exceeds REL_STD_MAX."""
    b = q.get("beta")
    if b is None or b.value is None or b.std is None or not math.isfinite(b.std):
        return q
    rel = b.std / abs(b.value) if b.value != 0 else math.inf
    if rel <= REL_STD_MAX:
        return q
    pct = f"{100 * rel:.0f} %" if math.isfinite(rel) else "infinite"
    out = dict(q)
    for k in OVER_BETA:
        if k in out:
            out[k] = estimate(None, None, reason=(
                f"the data do not fix beta = ds/da, the slope of the slip with acceleration "
                f"(least squares: {b.value:.3g} ± {b.std:.2g}, relative std {pct} > "
                f"{100 * REL_STD_MAX:.0f} %) and {_LABEL[k]} depends on it nonlinearly; an "
                "acceleration phase (or a known drawbar pull) would fix it"))
    return out

"""The one name of every parameter, and the fit.json keys accepted for it
(docs/library/parameters.md)."""

from __future__ import annotations

#: fit.json key (or other spelling) -> the parameter's one name
ALIASES = {"R_mm": "R", "D_mm": "D", "e_mm": "e", "s0_linear": "s0", "x_off_mm": "x_off",
           "y_off_mm": "y_off", "stiffness_N_per_mm": "k", "rolling_resistance": "C_rr",
           "mass_kg": "m"}
#: derived quantities that take a prior (not fixed or bounded): name -> derived() key
DERIVED = {"k": "stiffness_N_per_mm", "C_rr": "rolling_resistance"}

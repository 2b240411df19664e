"""fitlug: measure and explain the slippage of a crawler robot's rubber track.

The stages, each a sub-package, data flowing one way:
``vision`` (video -> trajectories) -> ``io`` (files) -> ``model`` (JAX track model) ->
``fit`` (least squares) -> ``explain`` (left-out physics) -> ``posterior`` (emcee)
-> ``report``.

The most used names are available here; they are imported on first use so that
``import fitlug`` stays cheap (no JAX, OpenCV or matplotlib at import time).
"""

from __future__ import annotations

import importlib

from ._errors import FitError as FitError, FitlugError as FitlugError, InputError as InputError
from ._version import __version__ as __version__

_LAZY = {
    "Recording": "io", "Rig": "io", "read_trajectories": "io", "write_trajectories": "io",
    "read_rig": "io", "find_rig": "io",
    "fit": "fit", "fit_many": "fit", "FitResult": "fit", "build_problem": "fit", "sample_posterior": "posterior", "Posterior": "posterior",
    "Scenario": "sim", "simulate": "sim", "write_simulation": "sim",
    "explain": "explain",
    "fit_json": "report", "write_report": "report",
    "CATALOG": "model", "Effect": "model", "register_effect": "model",
    "unregister_effect": "model",
    "campaign": "campaign", "CampaignResult": "campaign",
}


def __getattr__(name: str):
    if name in _LAZY:
        mod = importlib.import_module(f".{_LAZY[name]}", __name__)
        value = getattr(mod, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'fitlug' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))

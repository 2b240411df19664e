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
    "fit_many": "fit", "FitResult": "fit", "build_problem": "fit",
    "Parameters": "fit", "Parameter": "fit", "Prior": "fit", "parameters": "fit",
    "sample_posterior": "posterior", "Posterior": "posterior",
    "Scenario": "sim", "simulate": "sim", "write_simulation": "sim",
    "fit_json": "report", "write_report": "report", "summary": "report",
    "CATALOG": "model", "Effect": "model", "register_effect": "model",
    "unregister_effect": "model",
    "CampaignResult": "campaign",
}


#: the sub-packages, reachable as attributes after a bare ``import fitlug``. ``fit``,
#: ``explain`` and ``campaign`` are named after their main function: always the sub-package,
#: made callable (``fitlug.fit(rec, rig)`` calls ``fitlug.fit.fit``), whatever was imported
#: first; a function bound here would hide the sub-package's other names
#: (``fitlug.campaign.fit_points``), and the import system binds the module anyway.
_PACKAGES = ("fit", "explain", "campaign", "io", "vision", "model", "posterior", "report",
             "plot", "sim", "cli")


def __getattr__(name: str):
    if name in _PACKAGES:
        value = importlib.import_module(f".{name}", __name__)
        globals()[name] = value
        return value
    if name in _LAZY:
        mod = importlib.import_module(f".{_LAZY[name]}", __name__)
        value = getattr(mod, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'fitlug' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | set(_PACKAGES))

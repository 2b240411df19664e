"""A recording made ready to fit: the checks, then what the data say is not as it should
be, repaired or kept out and listed (fit.json).

In order: two runs in one file refused (fitlug.io names the line when it reads a file;
this guards recordings built in memory), identity swaps repaired (:mod:`._swaps`; they
depend on no axis convention), the axes brought to the contract's frame
(:mod:`._orient`), the plausibility checks (:mod:`._checks`), tracks that are not
markers kept out (:mod:`._spurious`), and the sigma_mm column's holes and absurd values
handled (:mod:`._sigma`). On a clean recording all of it costs a few hundredths of a
second.
"""

from __future__ import annotations

from .._errors import InputError
from . import _orient, _sigma, _spurious, _swaps
from ._checks import check_coordinates, check_marker_ids, check_recording


def prepare(rec, rig) -> tuple:
    """(recording to fit, findings for the problem's init_info): "orientation", "swaps",
    "excluded", "sigma_notes".

    Raises:
        InputError: what check_recording refuses, and two runs in one file.
    """
    from ..io._runs import find_restart, restart_problem

    check_coordinates(rec)  # first: an overflowing coordinate upsets every step below
    check_marker_ids(rec)  # and the steps below loop over the markers
    restart = find_restart(rec)
    if restart is not None:
        raise InputError(rec.path, restart_problem(restart))
    rec, swaps = _swaps.find_and_repair(rec)  # before the axes: a swap upsets the travel
    rec, orientation = _orient.orient(rec)
    rec = check_recording(rec, rig)
    rec, excluded = _spurious.find_and_exclude(rec)
    rec, notes = _sigma.check_sigma(rec)
    return rec, {"orientation": orientation, "swaps": swaps, "excluded": excluded,
                 "sigma_notes": notes}

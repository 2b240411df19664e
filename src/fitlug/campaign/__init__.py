"""Campaigns (MODEL.md §4): many recordings of one track -> its traction-slip law.

``campaign(sources, ...)`` fits every recording in full (on Dask workers), then the shared
law (linear or Janosi-Hanamoto), k, C_rr per ground (F_max per ground when sliding) with
an emcee posterior, flags the recordings that disagree, and writes campaign.json and
campaign.html.
"""

from ._job import fit_recording as fit_recording, point_of_fit as point_of_fit
from ._model import Point as Point, fit_law as fit_law
from ._law import fit_points as fit_points
from ._result import (
    CampaignResult as CampaignResult,
    RecordingOutcome as RecordingOutcome,
    write_campaign as write_campaign,
)
from ._run import campaign as campaign
from ._sources import resolve_sources as resolve_sources

from .._callable import make_callable as _make_callable

_make_callable(__name__)  # `fitlug.campaign(...)` calls the function even when bound to this module

"""A track of rigid links: the chain's polygon round the wheels (MODEL.md §2, "Real tracks").

A chain of links of pitch c (or a belt with stiff lug shoes) wraps each wheel as a polygon:
the hinges sit on a circle, each link is a chord of it, and a marker fixed to a link turns
with the link. Three things follow that the idealised belt does not do: the belt travels
c / (2 asin(c / 2 Rh)) per wheel radian, not the hinge radius Rh; the links' middles run
inside the hinge circle on the arcs (by Rh (1 - cos(c / 2 Rh)), 1.7 mm on the reference
geometry); and the marker enters and leaves an arc in a link's kink, not on a smooth
curve. The path is drawn in :func:`fitlug.model._path._polygon`; the fitted R stays the
belt's travel per wheel radian, so that P = 2D + 2 pi R and the belt's lug count hold as
for a belt. The parameter is the link pitch c; the identity is a belt (c = 0).
"""

from __future__ import annotations

from ._base import Effect


class ChainPolygon(Effect):
    """Markers on a chain of rigid links of pitch `link_pitch` (mm) round the wheels."""

    id = "chain_polygon"
    defaults = {"link_pitch": 0.0}
    scales = {"link_pitch": 1.0}
    meaning = ("The track is a chain of rigid links (or stiff lug shoes): round the wheels it "
               "is a polygon, not a circle, so the links' middles run inside the wheel's "
               "pitch circle and the markers turn with their links.")
    searched = False  # fitted by name; see the module docstring
    signature = "x:lug:arcs"

    @classmethod
    def link(cls, p):
        return p["link_pitch"]

    @classmethod
    def report(cls, p):
        return {"link_pitch_mm": abs(float(p["link_pitch"]))}

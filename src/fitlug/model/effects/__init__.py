"""The catalog of left-out physics (MODEL.md §3): one module per effect, plus plugins."""

from ... import _exported

from ._base import Ctx as Ctx, Effect as Effect
from ._body_bounce import BodyBounce
from ._belt_sag import BeltSag
from ._camera_tilt import CameraTilt
from ._chain_polygon import ChainPolygon
from ._frame_drop import FrameDrop
from ._ground_sinkage import GroundSinkage
from ._lens_distortion import LensDistortion
from ._lug_ripple import LugRipple
from ._lug_memory import LugMemory
from ._lug_shear import LugShear
from ._lug_sliding import LugSliding
from ._marker_depth import MarkerDepth
from ._wheel_runout import WheelRunout

from ._registry import (
    CATALOG as CATALOG,
    Catalog as Catalog,
    _builtin,
    code_identity,
    plugins as plugins,
    register_effect as register_effect,
    unregister_effect as unregister_effect,
)

#: id -> effect class, in the order of MODEL.md's table, then plugins
_builtin(LugRipple, BodyBounce, LugSliding, BeltSag, GroundSinkage, WheelRunout,
         LensDistortion, MarkerDepth, CameraTilt, FrameDrop, LugShear, LugMemory,
         ChainPolygon)
_exported.add_identity(code_identity)


def get(effect_id: str) -> type[Effect]:
    """The effect class for a catalog id; ValueError naming the known ids otherwise."""
    try:
        return CATALOG[effect_id]
    except KeyError:
        raise ValueError(f"unknown effect {effect_id!r}; known: {', '.join(CATALOG)}") from None

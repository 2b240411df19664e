"""Find the physics the base model left out (MODEL.md §3): detect, locate, explain."""

from ._detect import ALPHA as ALPHA, Detection as Detection, detect as detect
from ._explain import explain as explain
from ._explanation import Explanation as Explanation, Step as Step
from ._locate import Location as Location, locate as locate
from ._table import Geometry as Geometry, geometry as geometry

from .._callable import make_callable as _make_callable

_make_callable(__name__)  # `fitlug.explain(...)` calls the function even when bound to this module

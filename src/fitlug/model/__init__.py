"""The differentiable track model (MODEL.md §2) and its catalog of extensions (§3)."""

from ._model import (
    KINEMATIC as KINEMATIC,
    Layout as Layout,
    default_params as default_params,
    hermite as hermite,
    integrate as integrate,
    kinematics as kinematics,
    make_layout as make_layout,
    param_names as param_names,
    positions as positions,
    predict as predict,
    predict_from_nodes as predict_from_nodes,
    sampled_kinematics as sampled_kinematics,
    segments as segments,
    slip_law as slip_law,
    steady_slip as steady_slip,
)
from ._path import belt_length as belt_length, stadium as stadium
from ._physics import (
    delta_l as delta_l,
    physical as physical,
    reference_slip as reference_slip,
)
from ._knots import place_knots as place_knots
from .effects import (
    CATALOG as CATALOG,
    Ctx as Ctx,
    Effect as Effect,
    plugins as plugins,
    register_effect as register_effect,
    unregister_effect as unregister_effect,
)

"""Simulated recordings with known truth (MODEL.md §2 and any catalog effects), and the camera
simulator: recordings rendered as camera frames (`render_video`, `render_frames`,
`render_recording`; `_render`, `_render_video`, small test scenes in `_scene`, drive-through
clips in `_drive`) and tracks drawn on frames (`overlay_png`, `overlay_video`)."""

from ._profile import speed_profile as speed_profile
from ._scenario import REFERENCE_SLIP as REFERENCE_SLIP, Scenario as Scenario
from ._simulate import (
    rig_of as rig_of,
    scenario_from_json as scenario_from_json,
    simulate as simulate,
    truth_params as truth_params,
    write_simulation as write_simulation,
)
from ._campaign import (
    LIMIT_GROUNDS as LIMIT_GROUNDS,
    LIMIT_K as LIMIT_K,
    Run as Run,
    campaign_scenarios as campaign_scenarios,
    law_slip as law_slip,
    law_slope as law_slope,
    limit_runs as limit_runs,
    simulate_campaign as simulate_campaign,
    simulate_points as simulate_points,
)
from ._overlay import draw_markers as draw_markers
from ._overlay import overlay_png as overlay_png
from ._overlay import overlay_video as overlay_video
from ._render import RenderOptions as RenderOptions
from ._render import default_camera as default_camera
from ._render_video import RenderedFrame as RenderedFrame
from ._render_video import render_frames as render_frames
from ._render_video import render_recording as render_recording
from ._render_video import render_video as render_video

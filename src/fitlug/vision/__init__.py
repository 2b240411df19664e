"""The vision system: frames in, marker trajectories out.

Read frames (`open_source`), calibrate the camera (`calibrate`, `load_calibration`), find
and follow the markers (`track`, `Tracker`), map them to the ground frame in mm
(`to_recording`), measure the noise on a stationary recording (`measure_noise`), render
simulated recordings as camera frames (`render_video`, `render_recording`) and draw the
tracks on frames (`overlay_png`, `overlay_video`).

Importing this package does not import OpenCV or matplotlib; the functions that need
them import them when called.
"""

from ._calib_io import load_calibration as load_calibration
from ._calib_io import save_calibration as save_calibration
from ._calibrate import calibrate as calibrate
from ._calibrate import scale_from_board as scale_from_board
from ._calibrate import scale_from_points as scale_from_points
from ._calibration import Calibration as Calibration
from ._detect import Detections as Detections
from ._detect import detect_markers as detect_markers
from ._noise import NoiseResult as NoiseResult
from ._noise import format_noise as format_noise
from ._noise import measure_noise as measure_noise
from ._noise import noise_from_tracks as noise_from_tracks
from ._overlay import draw_markers as draw_markers
from ._overlay import overlay_png as overlay_png
from ._overlay import overlay_video as overlay_video
from ._pipeline import origin_of as origin_of
from ._pipeline import scale_calibration as scale_calibration
from ._pipeline import to_recording as to_recording
from ._pipeline import track as track
from ._qs import QsFit as QsFit
from ._qs import refine_qs as refine_qs
from ._refine import CogFit as CogFit
from ._refine import refine_cog as refine_cog
from ._render import RenderOptions as RenderOptions
from ._render import default_camera as default_camera
from ._render_video import RenderedFrame as RenderedFrame
from ._render_video import render_frames as render_frames
from ._render_video import render_recording as render_recording
from ._render_video import render_video as render_video
from ._source import FrameSource as FrameSource
from ._source import open_source as open_source
from ._track import Tracker as Tracker
from ._track import TrackerConfig as TrackerConfig
from ._track import TrackResult as TrackResult
from ._track import track_frames as track_frames

__all__ = [
    "open_source", "FrameSource",
    "calibrate", "Calibration", "load_calibration", "save_calibration", "scale_from_points",
    "scale_from_board",
    "track", "track_frames", "Tracker", "TrackerConfig", "TrackResult", "to_recording",
    "origin_of", "scale_calibration",
    "detect_markers", "Detections", "refine_cog", "CogFit", "refine_qs", "QsFit",
    "measure_noise", "noise_from_tracks", "NoiseResult", "format_noise",
    "render_video", "render_frames", "render_recording", "RenderOptions", "RenderedFrame",
    "default_camera",
    "overlay_png", "overlay_video", "draw_markers",
]

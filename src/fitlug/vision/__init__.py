"""The vision system: frames in, marker trajectories out.

Read frames (`open_source`), calibrate the camera (`calibrate`, `load_calibration`), find
and follow the markers (`track`, `Tracker`), map them to the ground frame in mm
(`to_recording`) and measure the noise on a stationary recording (`measure_noise`). The
camera simulator (rendering recordings as frames, drawing tracks on frames) is in
`fitlug.sim`.

Four rooms: `read` (video files, image folders, Phantom .cine), `calibrate` (boards,
intrinsics, scale, calib.json), `detect` (finding markers and their subpixel centres) and
`track` (following markers frame to frame, the video-to-trajectories pipeline, noise).
The functions `calibrate` and `track` exported here share their names with the
sub-packages `calibrate` and `track`; the imports below bind the functions last, so
`fitlug.vision.track` is the function (import sub-package modules with `from`).

Importing this package does not import OpenCV or matplotlib; the functions that need
them import them when called.
"""

from .read._source import FrameSource as FrameSource
from .read._source import open_source as open_source
from .calibrate._calib_io import load_calibration as load_calibration
from .calibrate._calib_io import save_calibration as save_calibration
from .calibrate._calibrate import calibrate as calibrate
from .calibrate._calibrate import scale_from_board as scale_from_board
from .calibrate._calibrate import scale_from_points as scale_from_points
from ..io._calibration import Calibration as Calibration
from .detect._detect import Detections as Detections
from .detect._detect import detect_markers as detect_markers
from .detect._qs import QsFit as QsFit
from .detect._qs import refine_qs as refine_qs
from .detect._refine import CogFit as CogFit
from .detect._refine import refine_cog as refine_cog
from .track._noise import NoiseResult as NoiseResult
from .track._noise import format_noise as format_noise
from .track._noise import measure_noise as measure_noise
from .track._noise import noise_from_tracks as noise_from_tracks
from .track._pipeline import origin_of as origin_of
from .track._pipeline import scale_calibration as scale_calibration
from .track._pipeline import to_recording as to_recording
from .track._pipeline import track as track
from .track._track import Tracker as Tracker
from .track._track import TrackerConfig as TrackerConfig
from .track._track import TrackResult as TrackResult
from .track._track import track_frames as track_frames

__all__ = [
    "open_source", "FrameSource",
    "calibrate", "Calibration", "load_calibration", "save_calibration", "scale_from_points",
    "scale_from_board",
    "track", "track_frames", "Tracker", "TrackerConfig", "TrackResult", "to_recording",
    "origin_of", "scale_calibration",
    "detect_markers", "Detections", "refine_cog", "CogFit", "refine_qs", "QsFit",
    "measure_noise", "noise_from_tracks", "NoiseResult", "format_noise",
]

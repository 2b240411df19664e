"""Files fitlug reads and writes (DATA.md): trajectories.csv, rig.toml, JSON outputs.

Every output is written atomically (temporary file, then rename); every bad input raises
`fitlug.InputError` naming the file, the line and the problem.
"""

from ._atomic import atomic_path as atomic_path
from ._atomic import write_bytes_atomic as write_bytes_atomic
from ._atomic import write_text_atomic as write_text_atomic
from ._fitjson import read_json as read_json
from ._fitjson import write_json as write_json
from ._formats import FORMATS as FORMATS
from ._formats import detect_format as detect_format
from ._formats import read_any as read_any
from ._formats import read_tracks as read_tracks
from ._imported import Tracks as Tracks
from ._netcdf import write_samples_netcdf as write_samples_netcdf
from ._recording import Recording as Recording
from ._recording import check_enough_samples as check_enough_samples
from ._recording import tracks_to_recording as tracks_to_recording
from ._rig import Rig as Rig
from ._rig import find_rig as find_rig
from ._rig import read_rig as read_rig
from ._rig import write_rig as write_rig
from ._trajectories import read_trajectories as read_trajectories
from ._write_trajectories import write_trajectories as write_trajectories

__all__ = [
    "Recording", "read_trajectories", "write_trajectories", "check_enough_samples",
    "Rig", "read_rig", "write_rig", "find_rig",
    "write_json", "read_json",
    "atomic_path", "write_text_atomic", "write_bytes_atomic", "write_samples_netcdf",
    "FORMATS", "detect_format", "read_tracks", "read_any", "Tracks", "tracks_to_recording",
]

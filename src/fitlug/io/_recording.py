"""`Recording`: the samples of one trajectories.csv, as flat arrays (one entry per sample)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError

ROLES = ("body", "lug")

# Optional per-sample columns and their dtypes, in the order they are written.
OPTIONAL_COLUMNS = {"frame": np.int64, "sigma": np.float64, "x_px": np.float64,
                    "y_px": np.float64, "quality": np.float64}


@dataclass(frozen=True, eq=False)
class Recording:
    """Positions of markers over time: one sample is one marker in one frame.

    All per-sample arrays have shape (S,). After `read_trajectories` the samples are sorted
    by (marker_index, t), so each marker's samples are contiguous and in time order.

    Attributes:
        markers: marker ids, in order of first appearance in the file.
        roles: 'body' or 'lug', one per marker.
        t: (S,) float64 time stamps, s.
        marker_index: (S,) int64 index into `markers`.
        x, y: (S,) float64 ground-frame position, mm (x along travel, y up); NaN where the
            marker was not found.
        sigma: (S,) float64 one-sigma position uncertainty, mm, or None.
        frame: (S,) int64 frame numbers, or None.
        x_px, y_px: (S,) float64 image position, px, or None.
        quality: (S,) float64 detector quality score, or None.
        meta: metadata from `# key: value` comment lines (values are strings after reading).
        path: the file it was read from, if any (not part of equality).

    Raises:
        ValueError: arrays of inconsistent shape, unknown roles, marker_index out of range.
    """

    markers: tuple[str, ...]
    roles: tuple[str, ...]
    t: np.ndarray
    marker_index: np.ndarray
    x: np.ndarray
    y: np.ndarray
    sigma: np.ndarray | None = None
    frame: np.ndarray | None = None
    x_px: np.ndarray | None = None
    y_px: np.ndarray | None = None
    quality: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    path: str | None = None

    def __post_init__(self):
        put = object.__setattr__  # frozen: normalise once, here
        put(self, "markers", tuple(str(m) for m in self.markers))
        put(self, "roles", tuple(str(r) for r in self.roles))
        put(self, "meta", dict(self.meta))
        if len(self.roles) != len(self.markers):
            raise ValueError(f"Recording: {len(self.markers)} markers but {len(self.roles)} roles")
        if len(set(self.markers)) != len(self.markers):
            raise ValueError("Recording: marker ids must be unique")
        bad = [r for r in self.roles if r not in ROLES]
        if bad:
            raise ValueError(f"Recording: role must be 'body' or 'lug', got {bad[0]!r}")
        for name in ("t", "x", "y"):
            put(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        put(self, "marker_index", np.asarray(self.marker_index, dtype=np.int64))
        for name, dtype in OPTIONAL_COLUMNS.items():
            value = getattr(self, name)
            if value is not None:
                put(self, name, np.asarray(value, dtype=dtype))
        n = self.t.shape
        if len(n) != 1:
            raise ValueError(f"Recording: t must be one-dimensional, got shape {self.t.shape}")
        for name in ("marker_index", "x", "y", *OPTIONAL_COLUMNS):
            value = getattr(self, name)
            if value is not None and value.shape != n:
                raise ValueError(f"Recording: {name} has shape {value.shape}, t has {n}")
        if self.marker_index.size and (self.marker_index.min() < 0
                                       or self.marker_index.max() >= len(self.markers)):
            raise ValueError("Recording: marker_index out of range of markers")

    # -- equality: exact, NaN equal to NaN, `path` ignored, meta compared as strings ----------
    def __eq__(self, other):
        if not isinstance(other, Recording):
            return NotImplemented
        if (self.markers, self.roles) != (other.markers, other.roles):
            return False
        if {k: str(v) for k, v in self.meta.items()} != {k: str(v) for k, v in other.meta.items()}:
            return False
        for name in ("t", "marker_index", "x", "y", *OPTIONAL_COLUMNS):
            a, b = getattr(self, name), getattr(other, name)
            if (a is None) != (b is None):
                return False
            if a is not None and not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
                return False
        return True

    __hash__ = None

    # -- helpers -----------------------------------------------------------------------------
    @property
    def n_markers(self) -> int:
        """Number of markers."""
        return len(self.markers)

    @property
    def n_samples(self) -> int:
        """Number of samples S (valid or not)."""
        return int(self.t.shape[0])

    def role_of(self, marker: str) -> str:
        """Role ('body' or 'lug') of marker id `marker`; KeyError if it is not in the recording."""
        try:
            return self.roles[self.markers.index(marker)]
        except ValueError:
            raise KeyError(f"no marker {marker!r} in this recording (markers: "
                           f"{', '.join(self.markers)})") from None

    def markers_of(self, role: str) -> np.ndarray:
        """Indices into `markers` of the markers with `role`, int64 (M,)."""
        _check_role(role)
        return np.array([i for i, r in enumerate(self.roles) if r == role], dtype=np.int64)

    def select(self, role: str) -> np.ndarray:
        """Indices of the samples whose marker has `role` ('body' or 'lug'), int64 (K,)."""
        return np.flatnonzero(np.isin(self.marker_index, self.markers_of(role)))

    def times(self) -> np.ndarray:
        """Unique frame times, sorted, s."""
        return np.unique(self.t)

    @property
    def valid(self) -> np.ndarray:
        """(S,) bool: the samples where the marker was found (x and y finite)."""
        return np.isfinite(self.x) & np.isfinite(self.y)

    @property
    def fps(self) -> float | None:
        """Frame rate, 1/s: meta 'fps' when given, else 1 / median step of the frame times.

        None when neither is available (fewer than two distinct times).
        """
        if "fps" in self.meta:
            try:
                value = float(self.meta["fps"])
            except (TypeError, ValueError):
                value = float("nan")
            if np.isfinite(value) and value > 0:
                return value
        steps = np.diff(self.times())
        if steps.size == 0:
            return None
        return float(1.0 / np.median(steps))

    @classmethod
    def from_dataframe(cls, df, *, fps: float | None = None, mm_per_px: float | None = None,
                       calibration=None, rig=None, body=None, lug=None,
                       likelihood: float = 0.6) -> "Recording":
        """A Recording from a pandas DataFrame, for notebooks.

        Takes the canonical long table (time_s, marker, role, x_mm, y_mm), trackpy's linked
        features (frame, particle, x, y in px; markers named by particle number) or a
        DeepLabCut table (MultiIndex columns; samples below `likelihood` missing). Pixels
        become mm through `calibration` (a `fitlug.vision.Calibration`) or the scale
        `mm_per_px` (y up), as `fit-lug track` maps them; time is frame / `fps`; roles
        from `rig`, `body`/`lug` lists (with `body` alone the rest are lugs) or the names.

        Raises:
            InputError: missing columns, pixels without a scale, no fps, unknown roles.
        """
        from ._fmt_trackpy import recording_from_dataframe

        return recording_from_dataframe(df, fps=fps, mm_per_px=mm_per_px,
                                        calibration=calibration, rig=rig, body=body, lug=lug,
                                        likelihood=likelihood)

    def with_(self, **changes) -> "Recording":
        """A copy with some fields replaced (validated like a new Recording)."""
        return dataclasses.replace(self, **changes)


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise ValueError(f"role must be 'body' or 'lug', got {role!r}")


def check_enough_samples(recording: Recording, n_params: int) -> None:
    """Raise InputError when the recording has fewer valid samples than `n_params`.

    A valid sample is one with finite x and y. The error names the recording's file.
    """
    n_valid = int(np.count_nonzero(recording.valid))
    if n_valid < n_params:
        raise InputError(recording.path,
                         f"fewer valid samples ({n_valid}) than parameters ({n_params})")

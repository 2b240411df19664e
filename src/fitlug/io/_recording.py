"""`Recording`: the samples of one trajectories.csv, as flat arrays (one entry per sample).

Also the ways to build one from what another tracker exported: `tracks_to_recording`
(a reader's `Tracks`) and `recording_from_dataframe` (behind `Recording.from_dataframe`:
a canonical long table, a trackpy or a DeepLabCut DataFrame). They live with the class
because `Recording.from_dataframe` needs them and they need the class.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from .._errors import InputError
from ._imported import Tracks, _roles, _times, span_rate

if TYPE_CHECKING:
    from ._rig import Rig

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
        return recording_from_dataframe(df, fps=fps, mm_per_px=mm_per_px,
                                        calibration=calibration, rig=rig, body=body, lug=lug,
                                        likelihood=likelihood)

    def __repr__(self) -> str:
        roles = {r: sum(1 for x in self.roles if x == r) for r in ROLES}
        t = self.times()
        span = f"{t[0]:.4g}-{t[-1]:.4g} s, {len(t)} frames" if len(t) else "no samples"
        return (f"<Recording {self.path or ''}: {roles.get('body', 0)} body and "
                f"{roles.get('lug', 0)} lug markers, {self.n_samples} samples, {span}>")

    def _repr_html_(self) -> str:
        import html

        return f"<code>{html.escape(repr(self))}</code>"

    def to_dataframe(self):
        """The samples as a pandas DataFrame in DATA.md's long form: columns time_s, marker,
        role, x_mm, y_mm, then sigma_mm, frame, x_px, y_px, quality where present (one row
        per sample; :meth:`from_dataframe` reads it back)."""
        from ._frames import recording_to_dataframe

        return recording_to_dataframe(self)

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


# -- building a Recording from another tracker's Tracks or a DataFrame -------------------------

def tracks_to_recording(tracks: Tracks, *, pixels_to_mm: Callable | None = None,
                        image_height: float | None = None, fps: float | None = None,
                        rig: "Rig | None" = None, body=None, lug=None) -> Recording:
    """A `Recording` in ground-frame mm from what another tracker exported.

    Args:
        tracks: a reader's output.
        pixels_to_mm: maps (..., 2) image points (px, origin top-left, y down) to ground mm
            (y up), e.g. a vision `Calibration`'s `pixels_to_mm` (plus its origin); when
            given, pixels are used even where the file also has world units (Tracker).
        image_height: image height, px, to turn pixels measured up from the bottom edge
            (DLTdv7) into the usual convention; for a scale alone any value gives the same
            result (the fit does not depend on where the origin is).
        fps: frame rate, 1/s: the time when the file has none; checked against the file's
            time stamps when it has them (2 %).
        rig: roles from its [markers] (and its [camera] fps when `fps` is not given).
        body, lug: marker names by role; with only `body`, every other marker is a lug.

    Raises:
        InputError: pixels without a mapping, no time and no fps, an fps that disagrees
            with the time stamps, a marker whose role cannot be told.
    """
    if fps is None and rig is not None:
        fps = rig.fps  # the time where the file has none, else checked against its stamps
    if pixels_to_mm is not None:
        if tracks.xy_px is None:
            raise InputError(tracks.path, f"the {tracks.format} file holds no pixel positions: "
                             f"--mm-per-px and --calib do not apply to it")
        px = tracks.xy_px.copy()
        if tracks.px_y_up:
            px[..., 1] = (image_height or 0.0) - px[..., 1]
        mm = np.asarray(pixels_to_mm(px), dtype=np.float64)
        units = "px mapped to mm"
    elif tracks.xy_mm is not None:
        mm, units = tracks.xy_mm, "mm"
    else:
        raise InputError(tracks.path, f"the {tracks.format} file holds positions in pixels: "
                         f"give their scale (--mm-per-px S) or a camera calibration (--calib "
                         f"calib.json)")
    t = _times(tracks, fps)
    roles = _roles(tracks, rig, body, lug)
    f, m = mm.shape[:2]
    rows = np.tile(np.arange(f), m)          # marker by marker, in time order
    cols = np.repeat(np.arange(m), f)
    optional = {}
    if tracks.xy_px is not None:
        optional["x_px"] = tracks.xy_px[rows, cols, 0]
        optional["y_px"] = tracks.xy_px[rows, cols, 1]
    if tracks.quality is not None:
        optional["quality"] = tracks.quality[rows, cols]
    extra = dict(tracks.meta)
    note = extra.pop("source_note", None)  # how the file was read, where it broke its format
    meta = {"source": f"{tracks.format} {os.path.basename(tracks.path)}"
                      + (f" ({note})" if note else ""), "units": "mm"}
    if t.size > 1:
        meta["fps"] = f"{span_rate(t, tracks.frame):.10g}"
    meta.update(extra)
    meta["positions"] = units
    rec = Recording(markers=tracks.markers, roles=tuple(roles), t=t[rows],
                    marker_index=cols.astype(np.int64), x=mm[rows, cols, 0], y=mm[rows, cols, 1],
                    frame=tracks.frame[rows], meta=meta, path=tracks.path, **optional)
    _warn_if_upside_down(rec, tracks.format)
    return rec


def upside_down_score(rec: Recording) -> float | None:
    """Correlation between a lug marker's height and its speed along the body's travel.

    On a crawler track the lugs stall on the ground (bottom) and run forward at about
    twice the body's speed over the top, so with y up the score is near +1; near -1 the
    y axis points down (a flipped image convention). None without body and lug markers
    or without travel."""
    body, lug = rec.select("body"), rec.select("lug")
    if body.size == 0 or lug.size == 0:
        return None
    ok = body[np.isfinite(rec.x[body])]
    if ok.size < 2:
        return None
    first, last = ok[np.argmin(rec.t[ok])], ok[np.argmax(rec.t[ok])]
    travel = rec.x[last] - rec.x[first]
    if not np.isfinite(travel) or travel == 0:
        return None
    heights, speeds = [], []
    for k in rec.markers_of("lug"):
        i = np.flatnonzero((rec.marker_index == k) & rec.valid)
        if i.size < 3:
            continue
        i = i[np.argsort(rec.t[i])]
        heights.append(rec.y[i][1:])
        speeds.append(np.sign(travel) * np.diff(rec.x[i]) / np.diff(rec.t[i]))
    if not heights:
        return None
    h, v = np.concatenate(heights), np.concatenate(speeds)
    if h.size < 10 or np.std(h) == 0 or np.std(v) == 0:
        return None
    return float(np.corrcoef(h, v)[0, 1])


def _warn_if_upside_down(rec: Recording, fmt: str) -> None:
    score = upside_down_score(rec)
    if score is not None and score < -0.5:
        import warnings

        warnings.warn(f"{rec.path}: the lug markers run fastest at the bottom of their path "
                      f"(height-speed correlation {score:.2f}): the y axis of this {fmt} file "
                      f"looks upside down (fitlug wants y up; check --y-origin, the "
                      f"format's pixel origin or --length-unit px)", stacklevel=3)


def recording_from_dataframe(df, *, fps=None, mm_per_px=None, calibration=None, rig=None,
                             body=None, lug=None, likelihood: float = 0.6):
    """See `Recording.from_dataframe`."""
    from ._fmt_trackpy import tracks_from_dataframe

    cols = set(map(str, df.columns)) if getattr(df.columns, "nlevels", 1) == 1 else set()
    if {"time_s", "marker", "role", "x_mm", "y_mm"} <= cols:
        markers = list(dict.fromkeys(map(str, df["marker"])))
        roles = dict(zip(map(str, df["marker"]), map(str, df["role"])))
        index = {m: k for k, m in enumerate(markers)}
        mi = np.array([index[str(m)] for m in df["marker"]], dtype=np.int64)
        t = np.asarray(df["time_s"], dtype=np.float64)
        order = np.lexsort((t, mi))
        return Recording(markers=tuple(markers), roles=tuple(roles[m] for m in markers),
                         t=t[order], marker_index=mi[order],
                         x=np.asarray(df["x_mm"], dtype=np.float64)[order],
                         y=np.asarray(df["y_mm"], dtype=np.float64)[order],
                         meta={"source": "DataFrame"})
    tracks = tracks_from_dataframe(df, likelihood=likelihood)
    to_mm = None
    height = None
    if calibration is None and mm_per_px is not None:
        # the scale-only calibration of `fit-lug track` (x = S x_px, y = S (H - y_px))
        from ._calibration import Calibration

        try:
            calibration = Calibration.from_scale(float(mm_per_px), (0, 0))
        except ValueError as exc:
            raise InputError(None, f"mm_per_px: {exc}") from None
    if calibration is not None:
        to_mm, height = calibration.pixels_to_mm, calibration.image_size[1]
    return tracks_to_recording(tracks, pixels_to_mm=to_mm, image_height=height, fps=fps,
                               rig=rig, body=body, lug=lug)

"""Follow markers from frame to frame, keeping their identities (`Tracker`, `track_frames`).

Each frame, every live track predicts where its marker is (a parabola through its last
five samples, else constant acceleration or velocity) and its marker is refined in a
small window there, all markers of a kind in one batch. A sample is kept only when it
looks like the marker it follows - COG: area (flux over interior level, which lighting
does not change), width and shape; QS: fit residual and contrast - and lies near the
prediction; else the frame is a gap (a partly hidden, merged or cut-off marker gives no
position rather than a wrong one). A track that misses is searched for around its
prediction for `max_gap` frames (a region detection), then closed: a lug marker seen
again later gets a new id; a body marker (a checker) found again near its closed track's
prediction with the same contrast gets its track back. New markers: a whole-frame search
on the first frame and every `redetect_every` frames; a cheap scan of the whole frame
every `scan_every` frames for bright spots that no track follows (`_scan`: markers coming
into view anywhere - across an edge, round a wheel, from behind an occluder, after an
empty start), each checked by a region detection; optionally a search along the frame's
edges every `edge_every` frames; and for `watch_frames` frames a region search where the
marker of a closed track would be (back from behind an occluder, or after samples that
failed the checks); a detection on a live track's marker is not a new marker.
The measuring of followed markers is in `_follow`, the searches for new ones in `_pickup`
(both mixed into `Tracker`).

The checks scale with the noise: a small disc (8-10 px across) in a noisy frame (sigma 4
grey levels) scatters in area and width several times more than the fixed tolerances
made for big discs allow. The lighting's slope across each marker is averaged along its
track rather than fitted afresh on the few pixels of one frame.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field

import numpy as np

from ..detect._detect import COG, QS, Detections, detect_markers, estimate_noise
from ..detect._qs import _SLOPES
from ._follow import Follow
from ._pickup import PickUp
from ._trackstate import ema, Track


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the tracker (sizes in px, times in frames).

    kinds: marker types to track; roles: role per kind (COG -> lug, QS -> body by default);
    cog_radius / qs_half: disc radius and half checker side if known (else measured on
    detection); min_contrast: least marker contrast, grey levels (default: from the noise);
    redetect_every: frames between full-frame searches for new markers; edge_every: frames
    between searches along the frame's edges for markers coming into view (0: never, the
    default: the scan below covers them);
    max_gap: frames a lost marker is searched for before its track is closed; max_step:
    the farthest a marker may move between two frames before its speed is known;
    min_quality: samples below it are gaps; min_length: shorter tracks are dropped;
    qs_iter: Levenberg-Marquardt steps per frame; watch_frames: frames for which the place
    a closed track's marker would be is searched (a small region detection each frame), so
    that a marker lost behind an occluder or to a bad sample is picked up again (under a
    new id) without waiting for the next whole-frame search; scan_every: frames between
    cheap scans of the whole frame (a quarter-size copy) for bright spots that no track
    follows - markers coming into view anywhere: across an edge, round a wheel, from behind
    an occluder, or in a recording that starts with nothing in view (0: never);
    scan_checks: the most spots checked (a region detection each) per scan.
    """

    kinds: tuple = (COG, QS)
    roles: dict = field(default_factory=lambda: {COG: "lug", QS: "body"})
    cog_radius: float | None = None
    qs_half: float | None = None
    min_contrast: float = 0.0
    redetect_every: int = 200
    edge_every: int = 0
    max_gap: int = 8
    max_step: float = 30.0
    min_quality: float = 0.5
    min_length: int = 5
    qs_iter: int = 1
    watch_frames: int = 40
    scan_every: int = 2
    scan_checks: int = 4


class Tracker(Follow, PickUp):
    """Stateful frame-by-frame tracker; feed frames in order with `step`, then `result`."""

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self.tracks: list[Track] = []
        self._live: list[Track] = []  # the tracks still followed (the per-frame loops: not
        # over every track a long recording ever had)
        self.frames = array("q")  # typed arrays: memory grows by 16 bytes a frame
        self.times = array("d")
        self.noise = None
        self.cog_radius = self.config.cog_radius
        self.qs_half = self.config.qs_half
        self._n = 0
        self._watch: list = []  # (closed track, last frame to search for its marker)
        self._radii: list = []  # radii of the discs of confirmed tracks
        self._checked: list = []  # (box px, last frame to leave it alone): spots of the
        # scan where nothing was found

    # -- helpers ---------------------------------------------------------------------------
    def _detect(self, frame, roi=None, kinds=None, scale=1, known=None, refine=True):
        cfg = self.config
        det = detect_markers(frame, kinds=kinds or cfg.kinds, cog_radius=self.cog_radius,
                             qs_half=self.qs_half, min_contrast=cfg.min_contrast, roi=roi,
                             noise=self.noise, scale=scale, known=known, refine=refine)
        # sizes measured on the first markers found make the later searches cheaper
        if self.cog_radius is None and np.any(det.kind == COG):
            self.cog_radius = float(np.median(det.size[det.kind == COG]))
        if self.qs_half is None and np.any(det.kind == QS):
            self.qs_half = float(np.median(det.size[det.kind == QS]))
        return det

    def _new_track(self, det: Detections, j: int, frame_no: int, qs_row=None):
        params = None
        if det.kind[j] == QS and qs_row is not None:
            params = det.extra["qs_params"][qs_row].copy()
        t = Track(len(self.tracks), str(det.kind[j]), det.size[j], frame_no, det.xy[j],
                   det.contrast[j], params)
        self.tracks.append(t)
        self._live.append(t)
        return t

    # -- one frame -------------------------------------------------------------------------
    def step(self, frame_no: int, time_s: float, frame: np.ndarray) -> None:
        """Track the markers in one frame (frames must come in increasing order)."""
        cfg = self.config
        if self.noise is None:
            self.noise = max(estimate_noise(frame), 1e-3)
        self.frames.append(int(frame_no))
        self.times.append(float(time_s))
        live = list(self._live)
        batch = {COG: [], QS: []}
        search = []
        for t in live:
            xy, unc = t.predict(frame_no)
            if unc is None or unc > 2.5:
                search.append((t, xy, unc))
            else:
                batch[t.kind].append((t, xy, unc))
        found = {}
        if batch[COG]:
            self._refine_cog(frame, frame_no, batch[COG], found)
        if batch[QS]:
            self._refine_qs(frame, frame_no, batch[QS], found)
        for t, xy, unc in search:
            self._search(frame, frame_no, t, xy, unc, found)
        self._accept(frame_no, found)
        if self._n % cfg.redetect_every == 0:
            self._watch.clear()
            self._pick_up(frame, frame_no)
        else:
            if self._watch:
                self._pick_up_lost(frame, frame_no)
            if cfg.edge_every and self._n % cfg.edge_every == 0:
                self._pick_up_at_edges(frame, frame_no)
            if cfg.scan_every and self._n % cfg.scan_every == 0:
                self._pick_up_anywhere(frame, frame_no)
        self._n += 1

    def _accept(self, frame_no, found):
        cfg = self.config
        uids = list(found)
        # two tracks on one marker: neither sample can be trusted
        if len(uids) > 1:
            # pairs nearer than the larger of their sizes; in order of x, only the pairs
            # closer in x than the largest size need the distance (a few Python
            # comparisons rather than an all-pairs array)
            pts = sorted((float(found[u][0][0]), float(found[u][0][1]), self.tracks[u].size, u)
                         for u in uids)
            reach = max(p[2] for p in pts)
            clash = set()
            for i, (xi, yi, si, ui) in enumerate(pts):
                for xj, yj, sj, uj in pts[i + 1:]:
                    if xj - xi >= reach:
                        break
                    if math.hypot(xj - xi, yj - yi) < max(si, sj):
                        clash.add(ui)
                        clash.add(uj)
            for u in clash:
                del found[u]
        for t in list(self._live):
            got = found.get(t.uid)
            if got is None or got[1] < cfg.min_quality:
                t.misses += 1
                if t.misses > cfg.max_gap or (not t.confirmed and t.misses > 1):
                    t.alive = False
                    self._live.remove(t)
                    if cfg.watch_frames > 0 and (t.confirmed or len(t.frames) >= 2):
                        self._watch.append((t, frame_no + cfg.watch_frames))
                continue
            xy, q, extra = got
            t.frames.append(frame_no)  # (Track.add, inlined)
            t.xs.append(float(xy[0]))
            t.ys.append(float(xy[1]))
            t.qs.append(float(q))
            t.misses = 0
            if len(t.frames) >= cfg.min_length:
                if not t.confirmed and t.kind == COG and cfg.cog_radius is None \
                        and t.radius is not None:
                    # the disc size the searches use: from the followed discs, not from the
                    # first one found (which may have been coming into view, half hidden)
                    self._radii.append(t.radius)
                    self.cog_radius = float(np.median(self._radii[-16:]))
                if not t.confirmed and t.kind == COG:
                    # its first samples of a disc still coming into view (smaller than it
                    # is whole, as its last sample measures it): their centres are off
                    t.sizes.append(float(extra[1]))
                    whole = 0.9 * t.sizes[-1]
                    while len(t.sizes) > 2 and t.sizes[0] < whole:
                        for a in (t.frames, t.xs, t.ys, t.qs, t.sizes):
                            a.pop(0)
                t.confirmed = True
                t.sizes = None
            elif t.kind == COG:
                t.sizes.append(float(extra[1]))
            if t.kind == COG:
                # the area and radius references: the mean of the first samples taken
                # through the streak's aperture, then a running average (weight 0.2). The
                # first sample, taken through a round one before the streak was known,
                # only seeds them: through it a small disc measures smaller (an 8 px disc
                # on its 16 px lug: 3 % in area, its annulus reaching the lug's edge) and a
                # running average seeded there was still 2.9 % low when the track was
                # confirmed and its tolerance narrowed (2.7 %): samples lost for 8 frames
                # (issue 45)
                first = t.shear is None
                if t.area is None:
                    t.area, t.radius, t.shear, t.slope = extra
                else:  # (ema, written out)
                    a = 0.2 if t.n_ref >= 5 else 1.0 / (t.n_ref + 1)
                    t.area = (1.0 - a) * t.area + a * extra[0]
                    t.radius = (1.0 - a) * t.radius + a * extra[1]
                    sh, sl = extra[2], extra[3]
                    t.shear = [0.8 * t.shear[0] + 0.2 * sh[0], 0.8 * t.shear[1] + 0.2 * sh[1]]
                    t.slope = [0.9 * t.slope[0] + 0.1 * sl[0], 0.9 * t.slope[1] + 0.1 * sl[1]]
                t.n_ref = 0 if first else t.n_ref + 1
                t.size = t.radius
            else:
                if extra[0] is not None:
                    t.rms = ema(t.rms, extra[0])
                t.contrast = float(extra[1])  # the last one: lighting drifts along the track
                p = np.array(extra[2], dtype=np.float64)
                if t.params is not None:  # the lighting's slopes: averaged along the track
                    p[_SLOPES] = 0.9 * t.params[_SLOPES] + 0.1 * p[_SLOPES]
                t.params = p

    # -- the outcome -----------------------------------------------------------------------
    def result(self) -> "TrackResult":
        """The confirmed tracks as arrays, ids given by role in order of first appearance."""
        cfg = self.config
        frames = np.asarray(self.frames, dtype=np.int64)
        keep = [t for t in self.tracks if len(t.frames) >= cfg.min_length]
        keep.sort(key=lambda t: (t.frames[0], t.xs[0]))
        pos = {f: i for i, f in enumerate(self.frames)}
        xy = np.full((frames.size, len(keep), 2), np.nan)
        quality = np.full((frames.size, len(keep)), np.nan)
        counters = {"body": 0, "lug": 0}
        ids, roles, kinds = [], [], []
        for m, t in enumerate(keep):
            rows = [pos[f] for f in t.frames]
            xy[rows, m, 0], xy[rows, m, 1] = t.xs, t.ys
            quality[rows, m] = t.qs
            role = cfg.roles.get(t.kind, "lug" if t.kind == COG else "body")
            counters[role] += 1
            ids.append(f"C{counters[role]}" if role == "body" else f"B{counters[role]:02d}")
            roles.append(role)
            kinds.append(t.kind)
        return TrackResult(ids, roles, kinds, frames, np.asarray(self.times), xy, quality)


@dataclass
class TrackResult:
    """Tracked markers: `markers` ids (body C1, C2, ...; lug B01, B02, ...), `roles`,
    `kinds` ('cog'/'qs'), `frames` (F,) frame numbers, `times` (F,) s, `xy_px` (F, M, 2)
    image positions (NaN: a gap), `quality` (F, M) in [0, 1] (NaN: a gap)."""

    markers: list
    roles: list
    kinds: list
    frames: np.ndarray
    times: np.ndarray
    xy_px: np.ndarray
    quality: np.ndarray

    @property
    def detection_rate(self) -> np.ndarray:
        """(M,) fraction of frames from each marker's first to its last sample with a sample."""
        ok = np.isfinite(self.xy_px[..., 0])
        out = np.zeros(ok.shape[1])
        for m in range(ok.shape[1]):
            idx = np.flatnonzero(ok[:, m])
            out[m] = idx.size / (idx[-1] - idx[0] + 1) if idx.size else 0.0
        return out


def track_frames(frames, *, config: TrackerConfig | None = None, total: int | None = None,
                 progress: bool = False) -> TrackResult:
    """Track markers through `frames`, an iterable of (frame_number, time_s, image (H, W)).

    total: number of frames (for the progress bar); progress: show a bar on stderr (only
    when stderr is a terminal).
    """
    tracker = Tracker(config)
    if progress:
        import sys

        from tqdm.auto import tqdm

        frames = tqdm(frames, total=total, desc="track", unit="frame", file=sys.stderr,
                      disable=not sys.stderr.isatty())
    for number, time_s, image in frames:
        tracker.step(number, time_s, image)
    return tracker.result()

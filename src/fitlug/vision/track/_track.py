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
from ..detect._qs import _B, _SLOPES, N_PARAMS, refine_qs
from ..detect._refine import refine_cog
from ._pickup import PickUp
from ._trackstate import ema, score, Track


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


class Tracker(PickUp):
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

    def _cog_quality(self, t, area, radius, shear):
        """How much a COG sample looks like the track's marker: a partly hidden or merged
        disc changes its area (flux over interior level, whatever the lighting), its width
        across the blur or its shape (traceless second moments, px²)."""
        if t.area is None:
            return 1.0
        # tolerances ~8x the scatter on clean frames of big discs (0.08 %, 0.07 %,
        # 0.015 px²): a disc that lost 0.6 % of its area at the rim has moved ~0.04 px and
        # scores 0.5. Small discs in noisy frames scatter more: their relative area and
        # radius by ~0.9 and ~0.6 noise / (contrast x radius) (8 px discs: 1.1 and 0.95),
        # their shear by ~1.4 noise / contrast px² (measured on renders, 8-15 px discs,
        # noise 2-4): the tolerances never go below 3.5 times 1.3, 1.1 and 1.6 that.
        rel = self.noise / max(t.contrast * t.radius, 1e-9)
        # the references of a young track rest on a few samples, the first of them taken
        # with a round aperture before the blur's direction was known: wider tolerances;
        # those of a marker coming into view at speed were taken through apertures that
        # differ by its streak (a streak of 2 px: 3 % in area and width, seen on
        # drive-throughs): wider still by the streak
        young = 1.0 if t.confirmed else 3.0 + self._blur(t)[0] - 0.25
        ds = math.hypot(shear[0] - t.shear[0], shear[1] - t.shear[1])
        return min(score(area / t.area - 1, young * max(0.006, 3.5 * 1.3 * rel)),
                   score(radius / t.radius - 1, young * max(0.005, 3.5 * 1.1 * rel)),
                   score(ds, young * max(0.12, 3.5 * 1.6 * rel * t.radius)
                         + 0.2 * math.hypot(*t.shear)))

    @staticmethod
    def _qs_contrast_tol(t):
        """Relative change of a checker's contrast allowed between samples: 10 %; the
        contrast of a checker under 10 px a side comes with its blur widths, which its few
        pixels fix poorly: 20 %; and more while the track is young (its reference from the
        detection's fit, which started without a previous frame)."""
        return (0.1 if t.size >= 5 else 0.2) * (1.0 if t.confirmed else 2.0)

    def _blur(self, t):
        """Motion-blur streak to allow for, px, and its direction (None: unknown), from the
        averaged shape: a streak L along angle φ makes the traceless second moments
        (L²/24)(cos 2φ, sin 2φ)."""
        if t.shear is None:
            return 1.0, None
        a, b = float(t.shear[0]), float(t.shear[1])
        # (less the shear noise leaves on a round disc, ~0.01 px², before the square root)
        length = math.sqrt(24.0 * max(math.hypot(a, b) - 0.01, 0.0)) + 0.25
        phi = 0.5 * math.atan2(b, a)
        return length, (math.cos(phi), math.sin(phi))

    def _refine_cog(self, frame, frame_no, items, found):
        tracks = [it[0] for it in items]
        blur = [self._blur(t) for t in tracks]
        known = all(d is not None for _, d in blur)
        # the lighting's slope across each disc, averaged along its track: fitted on the
        # few interior pixels of a small disc in one frame it is noisy enough to move the
        # centre by more than the slope itself does
        slopes = [t.slope for t in tracks]
        known_slopes = all(g is not None for g in slopes)
        # one array for the per-marker inputs: prediction, radius, streak, its direction
        # and the slope (one conversion from Python floats, not five)
        cols = np.array([(it[1][0], it[1][1], t.size, b) + (d if known else (0.0, 0.0))
                         + (tuple(g) if known_slopes else (0.0, 0.0))
                         for it, t, (b, d), g in zip(items, tracks, blur, slopes)])
        fit = refine_cog(frame, cols[:, 0:2], cols[:, 2], blur_px=cols[:, 3],
                         blur_dir=cols[:, 4:6] if known else None,
                         gain_slope=cols[:, 6:8] if known_slopes else None, stats=False)
        area = (fit.flux / np.where(fit.level > 0, fit.level, np.inf)).tolist()
        xy, radii, shear = fit.xy.tolist(), fit.radius.tolist(), fit.shear.tolist()
        slope = fit.slope.tolist()
        quality = self._cog_quality
        for i, t in enumerate(tracks):
            x, y = xy[i]
            if x != x:  # NaN: the window left the frame
                continue
            it = items[i]
            if math.hypot(x - it[1][0], y - it[1][1]) <= 1.0 + 3.0 * it[2]:
                found[t.uid] = (xy[i], quality(t, area[i], radii[i], shear[i]),
                                (area[i], radii[i], shear[i], slope[i]))

    def _refine_qs(self, frame, frame_no, items, found):
        cfg = self.config
        tracks = [it[0] for it in items]
        pred = np.array([it[1] for it in items])
        unc = max(it[2] for it in items)
        params = np.array([np.zeros(N_PARAMS) if t.params is None else t.params for t in tracks])
        warm = all(t.params is not None for t in tracks)
        half = np.array([t.size for t in tracks])
        fit = refine_qs(frame, pred, half, params=params if warm else None,
                        search=0 if unc < 0.75 else int(np.ceil(unc)) + 1, n_iter=cfg.qs_iter,
                        hold_slopes=warm)
        # a fit still on its way (residual well above the track's) gets more steps; "well
        # above": by more than the residual's own scatter (~1/sqrt(2 dof) relative, 17 % for
        # the few pixels of a small checker, which 1.2 x alone sent on 4 more steps in one
        # frame of six, converged fits all but never changed by them)
        xy, contrast, rms, dof = fit.xy.tolist(), fit.contrast.tolist(), fit.rms.tolist(), \
            fit.dof.tolist()
        slow = [i for i, t in enumerate(tracks) if abs(xy[i][0]) < math.inf
                and t.rms is not None and rms[i] > (1.0 + max(0.2, 2.0 / math.sqrt(
                    2.0 * max(dof[i], 1.0)))) * max(t.rms, self.noise)]
        if slow:
            slow = np.array(slow)
            held = fit.params[slow].copy()
            if warm:
                held[:, _SLOPES] = params[slow][:, _SLOPES]
            more = refine_qs(frame, fit.xy[slow], half[slow], params=held, search=0,
                             n_iter=4, hold_slopes=warm)
            for name in ("xy", "rms", "contrast", "params", "dof"):
                getattr(fit, name)[slow] = getattr(more, name)
            xy, contrast, rms, dof = fit.xy.tolist(), fit.contrast.tolist(), fit.rms.tolist(), \
                fit.dof.tolist()
        for i, t in enumerate(tracks):
            x, y = xy[i]
            if not (abs(x) < math.inf):
                continue
            q = score(contrast[i] / t.contrast - 1, self._qs_contrast_tol(t))
            if t.rms is not None:  # occlusion or a wrong fit: the residual jumps
                # (by more than its own scatter: ~1/sqrt(2 dof) relative, large for the few
                # pixels of a small checker)
                tol = max(0.25, 3.5 / math.sqrt(2.0 * max(dof[i], 1.0)))
                q = min(q, score(max(rms[i] / max(t.rms, self.noise) - 1, 0.0), tol))
            it = items[i]
            if math.hypot(x - it[1][0], y - it[1][1]) <= 1.0 + 3.0 * it[2]:
                found[t.uid] = (xy[i], q, (rms[i], contrast[i], fit.params[i]))

    def _search(self, frame, frame_no, t, xy, unc, found):
        cfg = self.config
        reach = cfg.max_step if unc is None else min(unc * 3.0 + 2.0, cfg.max_step * 2)
        pad = reach + 2.5 * t.size + 4
        roi = (xy[0] - pad, xy[1] - pad, xy[0] + pad + 1, xy[1] + pad + 1)
        # discs: the blobs found, refined once, with the track's radius and streak (the
        # same filter as a detection's: a contrast of 8 x the noise)
        det = self._detect(frame, roi=roi, kinds=(t.kind,), refine=t.kind != COG)
        if len(det) == 0:
            return
        if t.kind == COG:
            # (the aperture of the track's other samples, as `_refine_cog` takes them: a
            # disc streaking 2 px measures ~1.5 % wider through a round aperture than
            # through the streak's, and a sample so measured failed the checks against
            # references taken the other way - a track that missed one frame lost the
            # next ones too)
            length, direction = self._blur(t)
            n = det.xy.shape[0]
            fit = refine_cog(frame, det.xy, t.size, blur_px=length,
                             blur_dir=None if direction is None else np.tile(direction, (n, 1)),
                             n_iter=3)
            good = np.flatnonzero(np.isfinite(fit.xy[:, 0])
                                  & (fit.contrast > max(8.0 * self.noise, cfg.min_contrast)))
            if good.size == 0:
                return
            pos = fit.xy[good]
        else:
            pos = det.xy
        d = np.hypot(*(pos - np.asarray(xy)).T)
        order = np.argsort(d)
        j = order[0]
        if d[j] > reach or (d.size > 1 and d[order[1]] < 1.5 * d[j] + 2.0):
            return  # nothing there, or not clearly one marker
        if t.kind == COG:
            i = good[j]
            area = fit.flux[i] / fit.level[i] if fit.level[i] > 0 else 0.0
            extra = (area, fit.radius[i], fit.shear[i], fit.slope[i].tolist())
            q = self._cog_quality(t, area, fit.radius[i], fit.shear[i])
        else:
            row = int(np.flatnonzero(det.kind[:j + 1] == QS).size - 1)
            p = det.extra["qs_params"][row]
            q = score(p[_B] / t.contrast - 1, self._qs_contrast_tol(t))
            extra = (None, p[_B], p)
        found[t.uid] = (pos[j], q, extra)

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
                if not t.confirmed and t.kind == COG and t.radius is not None \
                        and t.first_size < 0.9 * t.radius and t.frames[1] == t.frames[0] + 1:
                    # its first sample was of a disc still coming into view (found before
                    # the size of the discs was known): its centre is off
                    for a in (t.frames, t.xs, t.ys, t.qs):
                        a.pop(0)
                t.confirmed = True
            if t.kind == COG:
                if t.area is None:
                    t.area, t.radius, t.shear, t.slope = extra
                else:  # (ema, written out)
                    t.area = 0.8 * t.area + 0.2 * extra[0]
                    t.radius = 0.8 * t.radius + 0.2 * extra[1]
                    sh, sl = extra[2], extra[3]
                    t.shear = [0.8 * t.shear[0] + 0.2 * sh[0], 0.8 * t.shear[1] + 0.2 * sh[1]]
                    t.slope = [0.9 * t.slope[0] + 0.1 * sl[0], 0.9 * t.slope[1] + 0.1 * sl[1]]
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

"""How a `Tracker` finds markers that no track follows (mixed into `Tracker`).

The whole-frame search (`_pick_up`, every `redetect_every` frames), the region searches
where closed tracks' markers would be (`_pick_up_lost`, which also gives a checker its
closed track back, `_reopen`), the cheap scan of the whole frame for bright spots
(`_pick_up_anywhere`, `_scan`), the optional strips along the edges (`_pick_up_at_edges`)
and the start of new tracks (`_add_new`). The state (tracks, sizes, noise, watch list)
is the `Tracker`'s.
"""

from __future__ import annotations

import math

import numpy as np

from ..detect._detect import COG, QS, Detections
from ..detect._scan import bright_spots
from ._trackstate import score


class PickUp:
    """The searches for new markers of `Tracker` (see the module's docstring)."""

    def _search_scale(self):
        """Shrink factor of the image searched for each kind: with its size known and the
        marker big enough, a half-size image (4-5 times cheaper). Measured on hard renders
        (noise 4, blur, a lighting gradient) every disc 8-10 px across and every checker
        10 px a side was found at half size as at full size; checkers 8 px a side were
        not (half of them) and stay at full size."""
        return {COG: 2 if self.cog_radius is not None and self.cog_radius >= 3.5 else 1,
                QS: 2 if self.qs_half is not None and self.qs_half >= 4.75 else 1}

    def _known(self, frame_no):
        """The markers the live tracks sampled in this frame, {kind: (xy, radius)}: a
        search for new markers need not refine the candidates on them (`_add_new` would
        drop their detections, which lie within twice the radius)."""
        out = {}
        for t in self._live:
            if t.frames[-1] == frame_no:
                xy, r = out.setdefault(t.kind, ([], []))
                xy.append((t.xs[-1], t.ys[-1]))
                r.append(t.size)
        return out

    def _pick_up(self, frame, frame_no):
        """Whole-frame search for markers no track follows."""
        self._add_new(self._detect(frame, scale=self._search_scale(),
                                   known=self._known(frame_no)), frame_no)

    def _pick_up_lost(self, frame, frame_no):
        """Search where the markers of recently closed tracks would be now (their
        prediction, the region growing with the time since their last sample); a marker
        found there that no live track follows starts a new track."""
        cfg = self.config
        h, w = frame.shape
        keep = []
        for t, until in self._watch:
            if frame_no > until:
                continue
            (px, py), unc = t.predict(frame_no)
            k = frame_no - t.frames[-1]
            reach = cfg.max_step if unc is None else min(unc * 3.0 + 2.0 + 0.5 * k,
                                                         cfg.max_step * 2)
            pad = reach + 2.5 * t.size + 4
            if not (-pad < px < w + pad and -pad < py < h + pad):
                continue  # gone out of the picture
            n_before = len(self.tracks)
            det = self._detect(frame, roi=(px - pad, py - pad, px + pad + 1, py + pad + 1),
                               kinds=(t.kind,), known=self._known(frame_no))
            if len(det):
                d = np.hypot(*(det.xy - np.array([px, py])).T)
                near = d <= reach
                if near.any():
                    sel = np.flatnonzero(near)
                    if sel.size == 1 and self._reopen(t, det, int(sel[0]), frame_no):
                        continue  # the same marker, back: its track goes on
                    det = Detections(det.xy[sel], det.kind[sel], det.size[sel], det.contrast[sel],
                                     {k_: v[np.flatnonzero(near[det.kind == QS])]
                                      for k_, v in det.extra.items()})
                    self._add_new(det, frame_no)
            if len(self.tracks) == n_before:
                keep.append((t, until))
        self._watch = keep

    def _reopen(self, t, det, j, frame_no):
        """Give a closed track its marker back when the tracker can tell it is the same:
        a body marker (QS: rigid with the body, few and far apart), the one checker found
        near its prediction, with the same contrast (sign and size within 25 %), and no
        other closed checker predicted near it. Lug markers are many, alike and close
        together: a lug marker seen again gets a new track (the fit joins fragments)."""
        if t.kind != QS or det.kind[j] != QS or t.params is None:
            return False
        c = float(det.contrast[j])
        if c * t.contrast <= 0 or abs(c / t.contrast - 1.0) > 0.25:
            return False
        x, y = det.xy[j]
        for o, until in self._watch:
            if o is not t and o.kind == QS and frame_no <= until:
                (px, py), _ = o.predict(frame_no)
                if math.hypot(px - x, py - y) < 4.0 * o.size:
                    return False
        row = int(np.flatnonzero(det.kind[:j + 1] == QS).size - 1)
        t.add(frame_no, (x, y), score(c / t.contrast - 1.0, self._qs_contrast_tol(t)))
        t.params = np.array(det.extra["qs_params"][row], dtype=np.float64)
        t.contrast = c
        t.rms = None  # (its residual's reference: learnt afresh, as a new track's)
        t.alive = True
        self._live.append(t)
        return True

    def _pick_up_at_edges(self, frame, frame_no):
        """Markers come into view across the frame's edges: search the strips along them
        where something stands out (a cheap test on every third pixel first)."""
        known = [r for r in (self.cog_radius, self.qs_half) if r is not None]
        if not known:
            return
        h, w = frame.shape
        width = int(2.5 * max(known) + self.config.max_step + 4)
        if 2 * width >= min(h, w):
            return
        thresh = 10.0 * self.noise + self.config.min_contrast
        import cv2

        for x0, y0, x1, y1 in ((0, 0, width, h), (w - width, 0, w, h), (width, 0, w - width, width),
                               (width, h - width, w - width, h)):
            # a marker is > 8 px across: every third row (OpenCV's extrema of a view, a few
            # times faster than numpy's over a strided one)
            lo, hi = cv2.minMaxLoc(frame[y0:y1:3, x0:x1])[:2]
            if hi - lo < 2 * thresh:
                continue
            pad = int(2 * max(known)) + 2  # markers straddling the strip's inner side too
            roi = (max(x0 - pad, 0), max(y0 - pad, 0), min(x1 + pad, w), min(y1 + pad, h))
            self._add_new(self._detect(frame, roi=roi, scale=self._search_scale(),
                                       known=self._known(frame_no)), frame_no)

    def _pick_up_anywhere(self, frame, frame_no):
        """Markers coming into view anywhere (`_scan.bright_spots`): the spots that stand
        out where no live track's marker is (nor a closed track's, which `_pick_up_lost`
        looks for), each checked by a region detection. A place where nothing was found
        is left alone until the next scan, and for 4 scans once the same spot (unmoved,
        away from the picture's edges) was found empty 4 times in a row: a marker coming
        into view is half hidden for a few frames (it moves: checked at every scan), and
        something bright that is not a marker and stays put must not cost a detection at
        every scan."""
        cfg = self.config
        sizes = [r for r in (self.cog_radius, self.qs_half) if r is not None]
        size = max(sizes) if sizes else None
        self._checked = [c for c in self._checked if c[1] >= frame_no - 2 * cfg.scan_every]
        # (each: region px, last frame to leave it alone, times found empty, spot px)
        masked = [c[0] for c in self._checked if c[1] >= frame_no]
        for t in self._live:
            x, y = t.xs[-1], t.ys[-1]
            if t.frames[-1] != frame_no:
                (x, y), _ = t.predict(frame_no)
            # (round a disc: its dark lug, twice its radius, and the background between
            # two lugs, which stands out of the dark discs either side as a spot would)
            # (a lug's neighbour, 1.5 lugs away along the belt, stays clear of it)
            r = (3.0 if t.kind == COG else 2.0) * t.size + 3.0
            masked.append((x - r, y - r, x + r, y + r))
        for t, until in self._watch:
            if frame_no <= until:  # (where `_pick_up_lost` looks for it anyway)
                (x, y), unc = t.predict(frame_no)
                r = 2.0 * t.size + 3.0
                masked.append((x - r, y - r, x + r, y + r))
        # (a threshold of 8 x the noise, as a detection's - single pixels are looked at,
        # and the opening leaves the noise's peaks standing ~1.5 x the noise high - and
        # never under 16 grey levels: a marker's bright part stands out by a hundred)
        thresh = max(8.0 * self.noise, 16.0, 0.25 * cfg.min_contrast)
        pad = 48.0 if size is None else 2.5 * size + 6.0
        # (the opening's square: larger than a disc 1.3 x the known radius across, or a
        # checker's quarter; 32 px while no marker is known)
        span = 32.0 if size is None else 2.6 * max(self.cog_radius or 0.0, self.qs_half or 0.0)
        spots = bright_spots(frame, thresh, masked, max_spots=cfg.scan_checks, spot_px=pad,
                             size_px=span)
        h, w = frame.shape
        for x, y in spots:
            n_before = len(self.tracks)
            roi = (x - pad, y - pad, x + pad + 1, y + pad + 1)
            self._add_new(self._detect(frame, roi=roi, known=self._known(frame_no)), frame_no)
            if len(self.tracks) == n_before:
                # found empty before at the same place (to the quarter-size pixel): a thing
                # that stays put; one that moved, a marker coming in, is checked every scan
                # (at the picture's edges every scan: a lug marker laid on the ground there
                # creeps in with the slip, a fraction of a pixel a frame)
                fails = 1 + max((n for _, _, n, (x0, y0) in self._checked
                                 if abs(x - x0) < 2.0 and abs(y - y0) < 2.0), default=0)
                edge = min(x, y, w - 1 - x, h - 1 - y) < pad
                wait = 1 if fails < 4 or edge else 4 * cfg.scan_every
                self._checked.append((roi, frame_no + wait, fails, (x, y)))

    def _partly_hidden(self, xy, size, frame_no):
        """A disc found where a closed track's marker would be, smaller than that marker:
        the marker still partly hidden (by a bar, a post, a plate), its centre off (16 %
        smaller: 0.6 px); it is taken a frame or two later, whole. A disc is not compared
        with the other markers' size: discs of one recording differ (one 10 px across among
        13-16 px ones, taken for a partly hidden one, was never picked up: issue 45); a new
        marker's first samples taken while it came into view are dropped when its track
        is confirmed (`Tracker._accept`)."""
        for t, until in self._watch:
            if t.kind != COG or frame_no > until or t.radius is None or size >= 0.9 * t.radius:
                continue
            (px, py), unc = t.predict(frame_no)
            if math.hypot(px - xy[0], py - xy[1]) < 2 * t.size + 3 * (unc or 0):
                return True
        return False

    def _add_new(self, det, frame_no):
        """Start a track for each detection that no live track is following."""
        if len(det) == 0:
            return
        qs_rows = np.cumsum(det.kind == QS) - 1
        live = list(self._live)
        for j in range(len(det)):
            if det.kind[j] == COG and self._partly_hidden(det.xy[j], det.size[j], frame_no):
                continue
            near = False
            for t in live:
                if t.kind != det.kind[j]:
                    continue
                if t.frames[-1] == frame_no:
                    near = np.hypot(t.xs[-1] - det.xy[j, 0], t.ys[-1] - det.xy[j, 1]) < 2 * t.size
                else:
                    (px, py), unc = t.predict(frame_no)
                    gate = 2 * t.size + 3 * (unc or 0)
                    near = math.hypot(px - det.xy[j, 0], py - det.xy[j, 1]) < gate
                if near:
                    break
            if not near:
                live.append(self._new_track(det, j, frame_no,
                                            qs_rows[j] if det.kind[j] == QS else None))

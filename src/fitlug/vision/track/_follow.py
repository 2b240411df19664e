"""How a `Tracker` measures the markers it follows in a new frame (mixed into `Tracker`).

At the prediction, all markers of a kind in one batch: COG discs refined with the track's
radius, streak and lighting slope (`_refine_cog`), QS checkers fitted warm from the
track's parameters (`_refine_qs`); around the prediction, for a track that missed, a
region detection (`_search`). Each sample is scored against the track's references
(`_cog_quality`, `_qs_contrast_tol`, `_blur`); `Tracker._accept` keeps or drops it.
The state (tracks, sizes, noise) is the `Tracker`'s.
"""

from __future__ import annotations

import math

import numpy as np

from ..detect._detect import COG, QS
from ..detect._qs import _B, _SLOPES, N_PARAMS, refine_qs
from ..detect._refine import refine_cog
from ._trackstate import score


class Follow:
    """The per-frame measuring of followed markers of `Tracker` (see the module's docstring)."""

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
        # and they settle over the first ~10 samples after the confirmation (the aperture
        # with them, from the averaged radius and streak: a small disc's area and width
        # through it move by ~3 %, its annulus reaching the lug's edge): the tolerances
        # narrow over those samples, not at once (issue 45: a still 8 px disc lost 9 of its
        # first 16 frames)
        young = 3.0 + self._blur(t)[0] - 0.25
        if t.confirmed:
            young = 1.0 + (young - 1.0) * min(max((15 - t.n_ref) / 10.0, 0.0), 1.0)
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

"""Find markers anywhere in a frame (or a region): COG discs and QS checkers.

Used on the first frame, every few frames to pick up markers entering the view, and in
small regions to re-find a lost marker. Positions come out refined (`_refine`, `_qs`).

COG: pixels brighter than the local mean (box filter a few disc diameters wide) by more
than a threshold set from the noise; connected regions that are round (area, fill ratio
of the bounding box, aspect, farthest pixel against the equivalent radius).

QS: saddle points of the smoothed image (most negative Hessian determinant, local
extrema), kept only when the grey levels on circles around them follow the checker's
pattern: two light and two dark quarters - most of the profile's variance in the second
angular harmonic, a high correlation with a square wave, and the same phase at two radii.
The same circles measure the checker's size when it is not given.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ._qs import refine_qs
from ._refine import refine_cog

COG, QS = "cog", "qs"


@dataclass
class Detections:
    """Markers found in one frame: `xy` (N, 2) px (refined), `kind` (N,) 'cog'/'qs',
    `size` (N,) px (COG disc radius, QS half side), `contrast` (N,) grey levels (QS signed),
    `extra` per-kind refinement results (QS fit parameters) for warm starts."""

    xy: np.ndarray
    kind: np.ndarray
    size: np.ndarray
    contrast: np.ndarray
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    @classmethod
    def empty(cls) -> "Detections":
        return cls(np.zeros((0, 2)), np.zeros(0, dtype="<U3"), np.zeros(0), np.zeros(0))


def estimate_noise(img: np.ndarray) -> float:
    """Robust standard deviation of the pixel noise, grey levels, from differences of
    neighbouring pixels along rows (edges and markers are left out as outliers; the spread
    of the rest, not their median, so that the rounding of quiet 8-bit frames counts)."""
    sub = np.asarray(img[:: max(1, img.shape[0] // 200)], dtype=np.float32)
    d = np.diff(sub, axis=1).ravel()
    if d.size == 0:
        return 0.0
    mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    keep = d[np.abs(d) <= max(4.0 * mad, 2.0)]
    return float(np.sqrt(np.mean(keep.astype(np.float64) ** 2) / 2.0)) if keep.size else 0.0


def _find_cog(img, noise, r_range, min_contrast, shrunk=False):
    """Candidate discs: centres (K, 2) and equivalent radii (K,) px of `img`, and whether
    each is to be checked at full size (K,). shrunk: `img` is a frame shrunk for the
    search, where a disc may be only 3-5 px across: there the few pixels of a small blob
    do not tell a disc from a square, and one that fills its box is checked."""
    import cv2

    r_lo, r_hi = r_range
    k = int(2 * round(3 * r_hi) + 1)
    bg = cv2.blur(img, (k, k), borderType=cv2.BORDER_REFLECT)
    thresh = max(8.0 * noise, float(min_contrast))
    np.subtract(img, bg, out=bg)  # (in place, and the mask a view: no fresh whole-frame
    mask = (bg > thresh).view(np.uint8)  # arrays to fault in)
    # 16-bit labels when they cannot overflow (fewer set pixels than labels): the same
    # labelling, three times cheaper than 32-bit ones on a whole frame
    ltype = cv2.CV_16U if cv2.countNonZero(mask) < 65535 else cv2.CV_32S
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=ltype)
    if n <= 1:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool)
    x, y, w, h, area = (stats[1:, i].astype(np.float64) for i in range(5))
    fill = area / (w * h)
    # (a disc 4-5 px across straddling pixel boundaries fills ~0.55 of its 5 x 5 box, one
    # 3-4 px across all of its 3 x 3 or 4 x 4 box)
    tiny = shrunk & (area < 20)
    boxy = tiny & (fill >= 0.93)
    keep = (area >= np.pi * r_lo ** 2 * 0.7) & (area <= np.pi * r_hi ** 2 * 1.3) \
        & (fill > np.where(tiny, 0.5, 0.6)) & ((fill < 0.93) | boxy) & (w < 1.7 * h) \
        & (h < 1.7 * w)
    out, radii, check = [], [], []
    for i in np.flatnonzero(keep):
        x0, y0 = int(x[i]), int(y[i])
        ys, xs = np.nonzero(labels[y0:y0 + int(h[i]), x0:x0 + int(w[i])] == i + 1)
        c = cents[i + 1]
        req = np.sqrt(area[i] / np.pi)
        far = np.sqrt(((xs + x0 - c[0]) ** 2 + (ys + y0 - c[1]) ** 2).max()) + 0.5
        if far <= 1.15 * req + 0.7:  # a disc; a square's corner reaches 1.25 req
            out.append(c)
            radii.append(req)
            check.append(boxy[i])
    return (np.asarray(out, dtype=np.float64).reshape(-1, 2), np.asarray(radii),
            np.asarray(check, dtype=bool))


def ring_profiles(img, centres, radii, n_angles=32):
    """Grey levels on circles: (K, R, n_angles), bilinear; NaN outside the image."""
    phi = 2 * np.pi * np.arange(n_angles) / n_angles
    px = centres[:, 0, None, None] + radii[None, :, None] * np.cos(phi)
    py = centres[:, 1, None, None] + radii[None, :, None] * np.sin(phi)
    return ring_like(img, px, py)


def checker_pattern(profiles):
    """Per profile (..., A): (amplitude of the 2nd harmonic, its phase, correlation with
    the square wave of that phase, fraction of the variance in the 2nd harmonic)."""
    a = profiles.shape[-1]
    phi = 2 * np.pi * np.arange(a) / a
    p = profiles - profiles.mean(axis=-1, keepdims=True)
    f2 = (p * np.exp(-2j * phi)).sum(axis=-1)
    phase = -np.angle(f2)  # p ≈ amplitude · cos(2φ - phase)
    sqw = np.sign(np.cos(2 * phi - phase[..., None]))
    var = (p * p).sum(axis=-1)
    safe = np.where(var > 0, var, 1.0)
    corr = (p * sqw).sum(axis=-1) / np.sqrt(safe * a)
    frac = 2 * np.abs(f2) ** 2 / (a * safe)
    return 2 * np.abs(f2) / a, phase, np.where(var > 0, corr, 0.0), np.where(var > 0, frac, 0.0)


def _find_qs(img, noise, qs_half, min_contrast, max_candidates=200):
    import cv2

    sigma = 1.5 if qs_half is None else float(np.clip(0.12 * qs_half, 1.0, 4.0))
    g = cv2.GaussianBlur(img, (0, 0), sigma)
    ixx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    iyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    ixy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    resp = np.multiply(ixy, ixy, out=ixy)  # minus the Hessian determinant: large at saddles
    resp -= np.multiply(ixx, iyy, out=ixx)  # (in place: no fresh whole-frame arrays)
    k = int(2 * round(max(3.0, 0.5 * (qs_half or 6))) + 1)
    # local maxima above 2 % of the strongest (the strongest is one): the threshold first,
    # so that few pixels are left to list
    top_val = np.float32(cv2.minMaxLoc(resp)[1])
    if not top_val > 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    pts = cv2.findNonZero((resp > np.float32(0.02) * top_val).view(np.uint8))  # raster order
    pts = pts.reshape(-1, 2).astype(np.intp)
    xs, ys = pts[:, 0], pts[:, 1]
    vals = resp[ys, xs]
    # local maxima: the greatest in the k x k square around them (as a dilation says; for
    # a few pixels, only at them: indices clipped to the image repeat pixels of the
    # square, which leaves its maximum as it is)
    h, w = resp.shape
    if vals.size * k * k < resp.size // 4:
        off = np.arange(k) - k // 2
        around = resp[np.clip(ys[:, None, None] + off[:, None], 0, h - 1),
                      np.clip(xs[:, None, None] + off[None, :], 0, w - 1)]
        peak = vals >= around.reshape(vals.size, -1).max(axis=1)
    else:
        peak = vals >= cv2.dilate(resp, np.ones((k, k), np.uint8))[ys, xs]
    xs, ys, vals = xs[peak], ys[peak], vals[peak]
    top = np.argsort(vals)[::-1][:max_candidates]
    cand = np.stack([xs[top], ys[top]], axis=1).astype(np.float64)
    # to a fraction of a pixel by a parabola through the peak: the circles below are small
    x0, y0 = np.clip(xs[top], 1, w - 2), np.clip(ys[top], 1, h - 2)
    for axis, (lo, hi) in enumerate((((y0, x0 - 1), (y0, x0 + 1)), ((y0 - 1, x0), (y0 + 1, x0)))):
        rm, r0, rp = resp[lo], resp[y0, x0], resp[hi]
        den = rm - 2 * r0 + rp
        cand[:, axis] += np.where(den < 0, np.clip(0.5 * (rm - rp) / np.where(den < 0, den, -1),
                                                   -0.5, 0.5), 0.0)
    # (circles of a small checker kept >= 2 px out: nearer, the blur of the pixel, the
    # smoothing and the motion smear its quarters together)
    radii = np.arange(2.0, 41.0) if qs_half is None else \
        np.maximum(np.array([0.4, 0.57, 0.75]) * float(qs_half), [2.0, 2.4, 2.8])
    amp, phase, corr, frac = checker_pattern(ring_profiles(g, cand, radii))
    amp, corr, frac = (np.nan_to_num(v) for v in (amp, corr, frac))
    thresh = max(6.0 * noise, 0.5 * float(min_contrast))
    if qs_half is None:
        # size: the largest radius at which the pattern still has (nearly) full strength
        pattern = (corr > 0.85) & (frac > 0.6) & (amp > thresh)
        strong = pattern & (amp >= 0.85 * amp.max(axis=1, keepdims=True))
        last = radii.size - 1 - np.argmax(strong[:, ::-1], axis=1)
        upto = np.arange(radii.size)[None, :] <= last[:, None]
        good = strong.any(axis=1) & (pattern | ~upto | (radii < 3)).all(axis=1) & (radii[last] >= 4)
        half = radii[last]
        ph = phase[:, 2:5]
    else:
        # (a small checker's pixels round its square wave off: a looser correlation)
        good = ((corr > (0.85 if qs_half >= 5 else 0.8)) & (frac > 0.6)
                & (amp > thresh)).all(axis=1)
        half = np.full(cand.shape[0], float(qs_half))
        ph = phase
    dphase = np.angle(np.exp(1j * (ph - ph[:, :1])))
    good &= (np.abs(dphase) < 0.35).all(axis=1)
    return cand[good], half[good], vals[top][good]


def measure_qs_half(img, xy, angle, half_guess, noise):
    """Half side (M,) px of QS markers at known centres: where the grey level crosses half
    way between each quarter and the surface around it, on lines through the middles of
    the quarters (NaN where the marker does not stand out from its surroundings)."""
    h0 = np.asarray(half_guess, dtype=np.float64).reshape(-1, 1)
    t = np.linspace(-1.5, 1.5, 241)[None, :] * h0  # along a line, px
    est = []
    for axis in (0, 1):  # lines along u (x), then along v (y)
        for side in (-0.5, 0.5):
            for k in (-1.0, 0.0, 1.0):
                off = side * h0 + k  # the line's distance from the centre, px
                u, v = (t, off + 0 * t) if axis == 0 else (off + 0 * t, t)
                c, s_ = np.cos(angle)[:, None], np.sin(angle)[:, None]
                px = xy[:, 0, None] + c * u - s_ * v
                py = xy[:, 1, None] + s_ * u + c * v
                prof = ring_like(img, px, py)
                for sign in (-1, 1):
                    sel = lambda lo, hi: (sign * t >= lo * h0) & (sign * t <= hi * h0)
                    with warnings.catch_warnings():  # (a line off the picture: all NaN)
                        warnings.simplefilter("ignore", RuntimeWarning)
                        quad = np.nanmedian(np.where(sel(0.3, 0.8), prof, np.nan), axis=1)
                        bg = np.nanmedian(np.where(sel(1.25, 1.5), prof, np.nan), axis=1)
                    mid = 0.5 * (quad + bg)
                    d = (prof - mid[:, None]) * np.sign(quad - bg)[:, None]
                    # last sample inside (d > 0) going outwards from the middle of the quarter
                    inner = np.where(sel(0.3, 1.5) & (d > 0), sign * t, -np.inf).max(axis=1)
                    est_side = np.full(xy.shape[0], np.nan)
                    for i in range(xy.shape[0]):
                        if not np.isfinite(inner[i]) or abs(quad[i] - bg[i]) < 6 * noise:
                            continue
                        j = np.argmin(np.abs(sign * t[i] - inner[i]))
                        j2 = j + sign
                        if 0 <= j2 < t.shape[1] and d[i, j] > 0 >= d[i, j2]:
                            f = d[i, j] / (d[i, j] - d[i, j2])
                            est_side[i] = abs(t[i, j] + f * (t[i, j2] - t[i, j]))
                    est.append(est_side)
    est = np.array(est)
    ok = np.isfinite(est).sum(axis=0) >= 4
    out = np.full(xy.shape[0], np.nan)
    out[ok] = np.nanmedian(est[:, ok], axis=0)
    return out


def ring_like(img, px, py):
    """Bilinear grey levels at points (px, py) of any shape; NaN outside the image."""
    h, w = img.shape
    bad = ~(np.isfinite(px) & np.isfinite(py))
    if bad.any():  # (NaN centres: off the picture, without a cast warning)
        px, py = np.where(bad, -2.0, px), np.where(bad, -2.0, py)
    x0, y0 = np.floor(px).astype(np.int64), np.floor(py).astype(np.int64)
    fx, fy = px - x0, py - y0
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0 = np.clip(x0, 0, w - 2), np.clip(y0, 0, h - 2)
    v = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
         + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    return np.where(ok, v, np.nan)


def _suppress(xy, score, radius):
    """Keep the strongest of candidates closer than `radius` to each other."""
    order = np.argsort(score)[::-1]
    kept = []
    for i in order:
        if all(np.hypot(*(xy[i] - xy[j])) >= radius for j in kept):
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)


def detect_markers(frame: np.ndarray, *, kinds=(COG, QS), cog_radius=None, qs_half=None,
                   cog_radius_range=(3.5, 40.0), min_contrast: float = 0.0, roi=None,
                   noise: float | None = None, scale: int = 1, known=None,
                   refine: bool = True) -> Detections:
    """Find and refine COG and QS markers in a frame.

    frame: (H, W) grey image; kinds: which marker types to look for; cog_radius: kept
    for callers, unused: discs of any radius in cog_radius_range are found, each measured
    at its own size (discs of one recording differ); qs_half: half side of the checkers
    px if known (else measured); min_contrast: least marker contrast, grey levels (the
    default threshold is 8x the noise); roi: (x0, y0, x1, y1) px to search only there;
    noise: pixel noise std if known; scale: search on the frame shrunk by this factor
    (1 or 2; faster, for markers of known size), refine at full resolution; a dict
    {kind: factor} gives each kind its own; known: {kind: (xy (K, 2), radius (K,))} markers
    already followed (a tracker's live tracks): a candidate of that kind nearer to one of
    them than its radius is not refined nor returned (a tracker drops detections within
    twice the radius of its tracks), and known checkers keep discs off their light
    quarters as found ones do; refine: False gives the COG candidates unrefined (their
    blobs' centroids, their equivalent radii, contrast NaN), for a caller that refines
    them its own way.
    Returns Detections in full-frame pixels.
    """
    import cv2

    x0 = y0 = 0
    img = frame
    if roi is not None:
        h, w = frame.shape
        x0, y0 = max(int(roi[0]), 0), max(int(roi[1]), 0)
        x1, y1 = min(int(roi[2]), w), min(int(roi[3]), h)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return Detections.empty()
        img = frame[y0:y1, x0:x1]
    img = np.ascontiguousarray(img, dtype=np.float32)
    if noise is None:
        noise = estimate_noise(img)
    off = np.array([x0, y0], dtype=np.float64)
    shrunk = {1: img}

    def search_image(kind):
        """The image to search for `kind` and its shrink factor."""
        k = int(scale.get(kind, 1) if isinstance(scale, dict) else scale)
        if k <= 1 or min(img.shape) < 16 * k:
            return img, 1.0
        if k not in shrunk:
            shrunk[k] = cv2.resize(img, (img.shape[1] // k, img.shape[0] // k),
                                   interpolation=cv2.INTER_AREA)
        return shrunk[k], float(k)

    # a search pixel (i, j) covers full pixels k i .. k i + k - 1: its centre is k i + (k-1)/2
    to_full = lambda xy: xy * k + 0.5 * (k - 1) + off  # noqa: E731
    xy_l, kind_l, size_l, con_l = [], [], [], []
    extra = {}
    qs_xy, qs_hs = np.zeros((0, 2)), 0.0
    known = known or {}

    def unknown(kind, cand):
        """Which candidates (n, 2) lie farther from every known marker of `kind` than
        its radius."""
        if kind not in known or len(known[kind][0]) == 0 or cand.shape[0] == 0:
            return np.ones(cand.shape[0], bool)
        kxy, kr = (np.asarray(v, dtype=np.float64) for v in known[kind])
        d = np.hypot(*(cand[:, None, :] - kxy[None, :, :]).transpose(2, 0, 1))
        return (d >= kr[None, :]).all(axis=1)
    if QS in kinds:
        search, k = search_image(QS)
        s_noise = noise / k
        cand, half, score = _find_qs(search, s_noise, None if qs_half is None else qs_half / k,
                                     min_contrast)
        if cand.shape[0]:
            keep = _suppress(cand, score, max(4.0, float(np.median(half))))
            cand, half = to_full(cand[keep]), half[keep] * k
            new = unknown(QS, cand)
            cand, half = cand[new], half[new]
        if cand.shape[0]:
            hs = half if qs_half is None else np.full(half.shape, float(qs_half))
            fit = refine_qs(frame, cand, hs, search=max(2, int(k) + 1), n_iter=8)
            if qs_half is None:  # the ring scan gives the size to a pixel: measure it
                hm = measure_qs_half(img, fit.xy - off, fit.angle, hs, noise)
                hs = np.where(np.isfinite(hm) & (np.abs(hm - hs) < 0.35 * hs), hm, hs)
                fit = refine_qs(frame, fit.xy, hs, params=fit.params, search=0, n_iter=4)
            # (the fit window of a checker under 10 px a side reaches its blurred outer
            # edge, which the model leaves unexplained: a larger residual is allowed)
            good = np.isfinite(fit.xy).all(axis=1) & \
                (fit.rms < np.where(hs >= 5, 0.35, 0.5) * np.abs(fit.contrast))
            qs_xy, qs_hs = fit.xy[good], float(np.max(hs, initial=0.0))
            xy_l.append(qs_xy)
            kind_l.append(np.full(int(good.sum()), QS))
            size_l.append(hs[good])
            con_l.append(fit.contrast[good])
            extra["qs_params"] = fit.params[good]
        if QS in known and len(known[QS][0]):
            qs_xy = np.concatenate([qs_xy, np.asarray(known[QS][0], np.float64).reshape(-1, 2)])
            qs_hs = max(qs_hs, float(np.max(known[QS][1])))
    if COG in kinds:
        search, k = search_image(COG)
        s_noise = noise / k
        r_range = cog_radius_range  # (any size: one disc may be half the others', issue 45)
        cand, radii, check = _find_cog(search, s_noise, (r_range[0] / k, r_range[1] / k),
                                       min_contrast, shrunk=k > 1)
        if check.any():  # blobs of the shrunk image that fill their box: discs at full size?
            keep = ~check
            for i in np.flatnonzero(check):
                cx, cy = (int(round(v)) for v in cand[i] * k + 0.5 * (k - 1))
                pad = int(4 * r_range[1]) + 2
                xa, ya = max(cx - pad, 0), max(cy - pad, 0)
                found = _find_cog(img[ya:cy + pad + 1, xa:cx + pad + 1], noise, r_range,
                                  min_contrast)[0]
                keep[i] = bool((np.hypot(*(found + [xa, ya] - [cx, cy]).T) < 2.0).any())
            cand, radii = cand[keep], radii[keep]
        if cand.shape[0]:
            cand, radii = to_full(cand), radii * k
            if qs_xy.shape[0]:  # light quarters of a checker are not discs
                d = np.hypot(*(cand[:, None, :] - qs_xy[None, :, :]).transpose(2, 0, 1))
                far = (d > 2.0 * qs_hs).all(axis=1)
                cand, radii = cand[far], radii[far]
            new = unknown(COG, cand)
            cand, radii = cand[new], radii[new]
        if cand.shape[0] and not refine:
            xy_l.append(cand)
            kind_l.append(np.full(cand.shape[0], COG))
            size_l.append(radii)
            con_l.append(np.full(cand.shape[0], np.nan))
        elif cand.shape[0]:
            # each disc through an aperture of its own size, its blob's then the one it
            # measures (one sized for discs twice as large takes in a small disc's lug)
            fit = refine_cog(frame, cand, radii, blur_px=1.0, n_iter=3)
            ok = np.isfinite(fit.xy).all(axis=1) & (fit.radius > 0.5 * radii)
            if ok.any():
                again = refine_cog(frame, fit.xy[ok], fit.radius[ok], blur_px=1.0, n_iter=1)
                for name in ("xy", "contrast", "radius"):
                    getattr(fit, name)[ok] = getattr(again, name)
            good = np.isfinite(fit.xy).all(axis=1) & (fit.contrast > max(8.0 * noise, min_contrast))
            xy_l.append(fit.xy[good])
            kind_l.append(np.full(int(good.sum()), COG))
            size_l.append(fit.radius[good])
            con_l.append(fit.contrast[good])
    if not xy_l:
        return Detections.empty()
    return Detections(np.concatenate(xy_l), np.concatenate(kind_l), np.concatenate(size_l),
                      np.concatenate(con_l), extra)

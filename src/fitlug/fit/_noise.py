"""Measurement noise per role, from the data alone (independent of any model).

Fourth differences of a marker track at the frame rate cancel its smooth motion (a lug
marker's path on an arc contributes ~1e-4 mm at 100 fps) while the noise enters with
variance 70 sigma^2. Segment joins (where the path curvature jumps) give a few large
values per revolution, so the scale is first taken robustly (MAD), then refined as the
standard deviation of the values within 4 MADs (corrected for the clipping).
"""

from __future__ import annotations

import numpy as np

_BINOM4 = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
_VAR4 = float(np.sum(_BINOM4 ** 2))  # 70
_CLIP = 4.0
# variance of a standard normal truncated at +-4: 1 - 2*4*phi(4)/(2*Phi(4)-1)
_TRUNC_VAR = 1.0 - 2 * _CLIP * np.exp(-_CLIP ** 2 / 2) / np.sqrt(2 * np.pi) / (1 - 6.334e-5)


def fourth_differences(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """4th differences over runs of 5 consecutive, evenly spaced, finite samples."""
    if len(v) < 5:
        return np.empty(0)
    d4 = np.convolve(v, _BINOM4, mode="valid")
    dt = np.diff(t)
    step = np.median(dt) if len(dt) else 0.0
    even = np.abs(dt - step) <= 0.01 * step if step > 0 else np.zeros_like(dt, bool)
    ok = (even[:-3] & even[1:-2] & even[2:-1] & even[3:]) & np.isfinite(d4)
    return d4[ok]


def noise_from_differences(values: list[np.ndarray]) -> tuple[float, int]:
    """(sigma, number of differences) from a list of 4th-difference arrays."""
    d = np.concatenate(values) if values else np.empty(0)
    if len(d) < 10:
        return float("nan"), len(d)
    mad = 1.4826 * np.median(np.abs(d - np.median(d)))
    if mad == 0:
        return 0.0, len(d)
    keep = np.abs(d) <= _CLIP * mad
    sd = np.sqrt(np.mean(d[keep] ** 2) / _TRUNC_VAR)
    return float(sd / np.sqrt(_VAR4)), int(keep.sum())


def estimate_noise(rec) -> dict[str, float]:
    """Noise sigma (mm) per role from the recording: {'body': .., 'lug': ..}."""
    out = {}
    for role in ("body", "lug"):
        diffs = []
        for m, r in enumerate(rec.roles):
            if r != role:
                continue
            sel = (rec.marker_index == m) & np.isfinite(rec.x) & np.isfinite(rec.y)
            t = rec.t[sel]
            for v in (rec.x[sel], rec.y[sel]):
                diffs.append(fourth_differences(t, v))
        out[role] = noise_from_differences(diffs)[0]
    return out


def irregular_time_stamps(t: np.ndarray) -> str | None:
    """A phrase naming the spread of the frame intervals when the distinct time stamps `t`
    (s) are too irregular for the 4th differences (which need runs of five samples evenly
    spaced to 1 %: most steps off by more), else None. Explains "cannot estimate the noise"
    for time stamps with jitter (a camera's or a logger's clock)."""
    times = np.unique(t[np.isfinite(t)])
    if times.size < 6:
        return None
    d = np.diff(times)
    med = float(np.median(d))
    if not med > 0:
        return None
    k = np.maximum(np.rint(d / med), 1.0)
    single = d[k == 1]
    off = np.abs(d / k - med) > 0.01 * med
    if single.size < 5 or off.mean() < 0.5:
        return None
    lo, hi = np.percentile(single, [1, 99])
    return (f"the time stamps are irregular: consecutive frames are {1e3 * lo:.3g} to "
            f"{1e3 * hi:.3g} ms apart around {1e3 * med:.3g} ms, {100 * off.mean():.0f} % of "
            "the steps off by more than 1 %")

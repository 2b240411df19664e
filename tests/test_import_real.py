"""Other trackers' REAL exports (../shared/data/real/trackers, issue 29), read and checked
against numbers taken from the files themselves, independently of the readers:

- Tracker car.trk: pixel positions parsed here with a regex, mapped to world by OSP's
  ImageCoordSystem worked by hand for one sample (origin, angle in degrees, scale, y up,
  metres -> mm), and the frame times from delta_t;
- Tracker BallToss.trz: the ball is at the coordinate origin in its first marked frame
  (x = xorigin, y = yorigin in the XML), and its world path is a free fall: a parabola
  whose curvature is g = 9.8 m/s^2 (physics the reader knows nothing of);
- DeepLabCut CSV: every row, and the likelihood mask (< 0.6 -> missing) from the
  likelihood column read with the csv module.
"""

import csv
import math
import os
import re
import zipfile

import numpy as np
import pytest

from fitlug import InputError
from fitlug.io import detect_format, read_any, read_tracks
from shared_data import REAL

TRK = os.path.join(REAL, "trackers", "tracker")
DLC = os.path.join(REAL, "trackers", "deeplabcut",
                   "reachingvideo1shortDLC_resnet50_TESTNov4shuffle1_10.csv")
pytestmark = pytest.mark.skipif(not os.path.isdir(TRK), reason="../shared/data/real absent")


def _frames_by_regex(xml: str, track: str) -> dict[int, tuple[float, float]]:
    """The `[n]` -> (x, y) entries of one PointMass, found with regular expressions."""
    start = xml.index(f'<property name="name" type="string">{track}</property>')
    end = xml.index('name="keyFrames"', start)
    block = xml[start:end]
    pat = re.compile(r'name="\[(\d+)\]" type="object">\s*<object class="[^"]*PointMass\$FrameData">'
                     r'\s*<property name="x" type="double">([^<]+)</property>'
                     r'\s*<property name="y" type="double">([^<]+)</property>')
    return {int(n): (float(x), float(y)) for n, x, y in pat.findall(block)}


def test_tracker_car_trk_world_coordinates_by_hand():
    path = os.path.join(TRK, "car.trk")
    assert detect_format(path) == "tracker"
    tr = read_tracks(path)
    xml = open(path, encoding="utf-8").read()
    pts = _frames_by_regex(xml, "masa A")
    assert tr.markers == ("masa A",)
    assert tr.frame.tolist() == sorted(pts) and len(pts) == 53
    np.testing.assert_array_equal(tr.xy_px[:, 0], np.array([pts[k] for k in sorted(pts)]))
    # the coordinate system of the XML (fixed: frame 0 holds for all frames)
    x0, y0, ang, sx, sy = 615.9331476323121, 538.2729805013928, 1.273030020056704, \
        5763.384311147731, 5763.384311147731
    for k in (0, 26, 52):
        x, y = pts[k]
        a = math.radians(ang)  # stored in degrees
        u, w = (x - x0) / sx, -(y - y0) / sy  # scaled, y flipped up
        X = math.cos(a) * u + math.sin(a) * w  # rotate back by the x axis' angle
        Y = -math.sin(a) * u + math.cos(a) * w
        assert tr.xy_mm[k, 0, 0] == pytest.approx(1000 * X, abs=1e-9)  # length_unit m
        assert tr.xy_mm[k, 0, 1] == pytest.approx(1000 * Y, abs=1e-9)
    # OSP's world -> image transform (setTransform(sx cos, -sy sin, -sx sin, -sy cos, x0, y0))
    # maps the world points back onto the pixels
    a = math.radians(ang)
    Xw, Yw = tr.xy_mm[..., 0] / 1000, tr.xy_mm[..., 1] / 1000
    np.testing.assert_allclose(sx * math.cos(a) * Xw - sx * math.sin(a) * Yw + x0, tr.xy_px[..., 0],
                               atol=1e-9)
    np.testing.assert_allclose(-sy * math.sin(a) * Xw - sy * math.cos(a) * Yw + y0,
                               tr.xy_px[..., 1], atol=1e-9)
    # delta_t = 4.1667 ms (240 fps), startframe 0, starttime 0
    np.testing.assert_allclose(tr.t, tr.frame * 4.166666666666667e-3, rtol=1e-12)
    assert tr.image_size == (1280, 720)
    rec = read_any(path, body=["masa A"])
    assert rec.fps == pytest.approx(240.0)
    assert rec.meta["source"] == "tracker car.trk"
    assert rec.roles == ("body",)


def test_tracker_balltoss_trz_origin_and_free_fall():
    path = os.path.join(TRK, "BallToss.trz")
    assert detect_format(path) == "tracker-trz"
    tr = read_tracks(path)
    with zipfile.ZipFile(path) as zf:
        xml = zf.read("BallToss_BallToss.trk").decode()
    pts = _frames_by_regex(xml, "ball")
    assert tr.frame.tolist() == sorted(pts)
    first = min(pts)
    # the first marked point sits on the origin of the coordinate system
    assert pts[first] == (131.2767066180302, 207.85825951016153)
    np.testing.assert_allclose(tr.xy_mm[0, 0], [0.0, 0.0], atol=1e-9)
    # delta_t 66 ms: t = 0.066 * frame
    np.testing.assert_allclose(tr.t, 0.066 * tr.frame)
    # a thrown ball: y(t) is a parabola of curvature -g, x(t) a straight line
    t, x, y = tr.t, tr.xy_mm[:, 0, 0] / 1000, tr.xy_mm[:, 0, 1] / 1000
    g = -2 * np.polyfit(t, y, 2)[0]
    assert 9.0 < g < 10.6, g
    vx = np.polyfit(t, x, 1)[0]
    assert np.std(x - np.polyval(np.polyfit(t, x, 1), t)) < 0.01 * vx * (t[-1] - t[0])
    # the world y axis points up: the ball rises first
    assert y[1] > y[0]


def test_deeplabcut_csv_rows_and_likelihood_mask():
    assert detect_format(DLC) == "deeplabcut"
    with open(DLC, newline="") as fh:
        rows = list(csv.reader(fh))
    parts, coords = rows[1][1:], rows[2][1:]
    data = np.array([[float(v) for v in r[1:]] for r in rows[3:]])
    names = list(dict.fromkeys(parts))
    for threshold in (0.6, 0.5):
        tr = read_tracks(DLC, likelihood=threshold)
        assert tr.markers == tuple(names)
        assert tr.frame.tolist() == [int(r[0]) for r in rows[3:]]
        for m, name in enumerate(names):
            cx, cy, cl = (next(j for j in range(len(parts)) if parts[j] == name and coords[j] == c)
                          for c in ("x", "y", "likelihood"))
            keep = data[:, cl] >= threshold
            np.testing.assert_array_equal(np.isfinite(tr.xy_px[:, m, 0]), keep)
            np.testing.assert_array_equal(tr.xy_px[keep, m, 0], data[keep, cx])
            np.testing.assert_array_equal(tr.xy_px[keep, m, 1], data[keep, cy])
            np.testing.assert_array_equal(tr.quality[:, m], data[:, cl])
    # the default threshold is DeepLabCut's pcutoff, 0.6
    assert read_tracks(DLC).meta["likelihood_threshold"] == "0.6"
    # no time in the file: refused without an fps; pixels refused without a scale
    with pytest.raises(InputError, match="no time stamps: give the frame rate"):
        read_any(DLC, body=["objectA"], pixels_to_mm=lambda xy: xy)
    with pytest.raises(InputError, match="in pixels: give their scale"):
        read_any(DLC, body=["objectA"], fps=30)
    rec = read_any(DLC, body=["objectA"], fps=30, pixels_to_mm=lambda xy: 0.1 * xy)
    assert rec.roles == ("lug", "lug", "lug", "body")
    assert rec.quality is not None and rec.n_samples == 48

"""Calibration against OpenCV's published results and synthetic views of a known camera."""

from __future__ import annotations

import glob
import json
import os

import numpy as np
import pytest

from fitlug._errors import InputError
from fitlug.vision.calibrate._calib_io import load_calibration, save_calibration
from fitlug.vision.calibrate._calibrate import calibrate, scale_from_board, scale_from_points
from fitlug.io._calibration import Calibration

cv2 = pytest.importorskip("cv2")

import shared_data  # noqa: E402 - tests/ is on sys.path (conftest)

REAL = os.path.join(shared_data.REAL, "calibration")
CHESS = sorted(glob.glob(os.path.join(REAL, "opencv_chessboard", "left*.jpg")))
CHARUCO = sorted(glob.glob(os.path.join(REAL, "opencv_charuco", "img_*.jpg")))
needs_real = pytest.mark.skipif(len(CHESS) != 13 or len(CHARUCO) != 4,
                                reason="real calibration images not present")

# OpenCV's published result for its sample views (left_intrinsics.yml, flags=2)
PUBLISHED_F, PUBLISHED_C = 535.916, (342.283, 235.571)
PUBLISHED_PER_VIEW = [0.193, 1.182, 0.173, 0.193, 0.160, 0.180, 0.231, 0.242, 0.296, 0.167,
                      0.202, 0.381, 0.174]
# the README's recalibration with current OpenCV
RECAL_F, RECAL_C = 536.1, (342.4, 235.6)


# -- synthetic views ---------------------------------------------------------------------
def render_chessboard(k, dist, rvec, tvec, size, cols, rows, square_mm, supersample=2):
    """8-bit image of a chessboard (cols x rows inner corners) seen by camera (k, dist).

    Each pixel (supersampled) is undistorted to a ray, intersected with the board plane
    z = 0 of the board frame (x_cam = R x_board + t), and coloured by its square.
    """
    w, h = size
    off = (np.arange(supersample) + 0.5) / supersample - 0.5
    u = np.broadcast_to(np.arange(w)[None, :, None, None] + off[None, None, None, :],
                        (h, w, supersample, supersample))
    v = np.broadcast_to(np.arange(h)[:, None, None, None] + off[None, None, :, None],
                        (h, w, supersample, supersample))
    pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    n = cv2.undistortPoints(pts, k, dist, criteria=crit).reshape(-1, 2)
    rot, _ = cv2.Rodrigues(np.asarray(rvec, float))
    rays = np.column_stack([n, np.ones(len(n))]) @ rot  # rows: R^T d
    rt = rot.T @ np.asarray(tvec, float)
    s = rt[2] / rays[:, 2]
    xb = s[:, None] * rays[:, :2] - rt[:2]
    i, j = np.floor(xb[:, 0] / square_mm), np.floor(xb[:, 1] / square_mm)
    inside = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    val = np.where(inside & ((i + j) % 2 == 0), 30.0, 225.0)
    img = val.reshape(h, w, supersample, supersample).mean(axis=(2, 3))
    return np.round(img).astype(np.uint8)


def _pose(rvec, centre_cam, board_centre=(100.0, 62.5, 0.0)):
    rot, _ = cv2.Rodrigues(np.asarray(rvec, float))
    return rvec, np.asarray(centre_cam, float) - rot @ np.asarray(board_centre)


K_TRUE = np.array([[600.0, 0, 330.0], [0, 605.0, 245.0], [0, 0, 1]])
D_TRUE = np.array([-0.2, 0.08, 0.0, 0.0, 0.0])
POSES = [_pose([0.3, 0.2, 0.05], (-70, -50, 420)), _pose([-0.3, 0.25, -0.1], (70, -45, 430)),
         _pose([0.25, -0.3, 0.1], (-75, 50, 440)), _pose([-0.2, -0.3, 0.0], (75, 55, 420)),
         _pose([0.0, 0.0, 0.2], (0, 0, 380)), _pose([0.4, 0.0, 0.0], (0, 0, 450))]


@pytest.fixture(scope="module")
def synthetic_views():
    return [render_chessboard(K_TRUE, D_TRUE, r, t, (640, 480), 9, 6, 25.0) for r, t in POSES]


def test_synthetic_camera_recovered(synthetic_views):
    cal = calibrate(synthetic_views, "chessboard:9x6", square_mm=25)
    k = cal.camera_matrix
    assert k[0, 0] == pytest.approx(600.0, rel=3e-3)
    assert k[1, 1] == pytest.approx(605.0, rel=3e-3)
    assert abs(k[0, 2] - 330.0) < 2.0 and abs(k[1, 2] - 245.0) < 2.0
    assert cal.dist_coeffs.shape == (5,)
    assert cal.dist_coeffs[0] == pytest.approx(-0.2, abs=0.02)
    assert cal.rms_px < 0.3
    assert [v["image"] for v in cal.per_view] == [f"image[{i}]" for i in range(6)]
    assert not cal.outlier_views()
    assert cal.image_size == (640, 480)


# -- OpenCV's sample chessboard ----------------------------------------------------------
@needs_real
def test_opencv_sample_reproduced_with_its_corner_window():
    # OpenCV's calibration sample refines corners with an 11 px half-window
    cal = calibrate(CHESS, "chessboard:9x6", square_mm=25, flags=cv2.CALIB_FIX_ASPECT_RATIO,
                    subpix_window=11)
    k = cal.camera_matrix
    assert k[0, 0] == k[1, 1]
    for f, c in ((RECAL_F, RECAL_C), (PUBLISHED_F, PUBLISHED_C)):
        assert abs(k[0, 0] - f) < 0.5
        assert abs(k[0, 2] - c[0]) < 0.5 and abs(k[1, 2] - c[1]) < 0.5
    assert 0.35 <= cal.rms_px <= 0.45
    assert cal.dist_coeffs[0] == pytest.approx(-0.26637, abs=0.01)
    errors = [v["rms_px"] for v in cal.per_view]
    np.testing.assert_allclose(errors, PUBLISHED_PER_VIEW, atol=0.1)
    worst = cal.per_view[int(np.argmax(errors))]["image"]
    assert os.path.basename(worst) == "left02.jpg"
    assert [os.path.basename(p) for p in cal.outlier_views()] == ["left02.jpg"]


@needs_real
def test_opencv_sample_default_window_fits_better():
    # a corner window that fits the squares removes left02's misfit: every view is
    # ordinary and the RMS halves; the camera agrees with the published one within 1 %
    cal = calibrate(CHESS, "chessboard:9x6", square_mm=25, flags=cv2.CALIB_FIX_ASPECT_RATIO)
    assert cal.rms_px < 0.25 < 0.393
    assert max(v["rms_px"] for v in cal.per_view) < 0.3
    assert not cal.outlier_views()
    assert cal.camera_matrix[0, 0] == pytest.approx(PUBLISHED_F, rel=0.01)
    assert abs(cal.camera_matrix[0, 2] - PUBLISHED_C[0]) < 3
    assert abs(cal.camera_matrix[1, 2] - PUBLISHED_C[1]) < 3


@needs_real
def test_charuco_tutorial():
    cal = calibrate(CHARUCO, "charuco:5x7", square_mm=40, marker_mm=20, dictionary="DICT_6X6_250")
    k = cal.camera_matrix
    assert k[0, 0] == pytest.approx(452.51, rel=0.015)
    assert k[1, 1] == pytest.approx(456.77, rel=0.015)
    assert abs(k[0, 2] - 317.70) < 5 and abs(k[1, 2] - 277.75) < 5
    assert cal.rms_px < 0.5
    assert len(cal.per_view) == 4 and not cal.rejected
    # the wrong dictionary finds no board
    with pytest.raises(InputError, match="found in 0 of 4"):
        calibrate(CHARUCO, "charuco:5x7", square_mm=40, marker_mm=20, dictionary="DICT_4X4_50")


@needs_real
def test_published_yaml_loads():
    cal = load_calibration(os.path.join(REAL, "opencv_chessboard", "left_intrinsics.yml"))
    assert cal.camera_matrix[0, 0] == pytest.approx(PUBLISHED_F, abs=1e-3)
    assert cal.image_size == (640, 480) and cal.rms_px == pytest.approx(0.3926, abs=1e-4)
    assert cal.flags == 2


# -- scale and the pixel -> ground mapping -------------------------------------------------
def _project(k, dist, xyz):
    img, _ = cv2.projectPoints(np.asarray(xyz, float).reshape(-1, 3), np.zeros(3), np.zeros(3),
                               k, dist)
    return img.reshape(-1, 2)


def test_scale_from_two_points():
    k = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    dist = np.array([-0.25, 0.1, 0.001, -0.001, 0.0])
    z = 1000.0  # plane of motion 1 m from the camera: S = z / f = 1.25 mm/px
    p = _project(k, dist, [[-150.0, 100.0, z], [170.0, -90.0, z]])
    d = np.hypot(320.0, 190.0)
    cal = Calibration(k, dist, (640, 480))
    assert scale_from_points(p[0], p[1], d, cal) == pytest.approx(z / 800.0, rel=1e-6)
    assert abs(scale_from_points(p[0], p[1], d) - z / 800.0) > 0.01  # distortion matters
    with pytest.raises(ValueError):
        scale_from_points(p[0], p[0], d)
    with pytest.raises(ValueError):
        scale_from_points(p[0], p[1], -1.0)


def test_scale_from_board_fronto_parallel():
    k = np.array([[600.0, 0, 330], [0, 600.0, 245], [0, 0, 1]])
    img = render_chessboard(k, D_TRUE, *_pose([0, 0, 0], (0, 0, 500)), (640, 480), 9, 6, 25.0)
    cal = Calibration(k, D_TRUE, (640, 480))
    s = scale_from_board(img, "chessboard:9x6", 25.0, cal)
    assert s == pytest.approx(500.0 / 600.0, rel=2e-3)
    with pytest.raises(InputError, match="scale image"):
        scale_from_board(np.full((100, 100), 128, np.uint8), "chessboard:9x6", 25.0, cal)


def test_pixels_to_mm_matches_ground_truth():
    k = np.array([[700.0, 0, 330], [0, 700.0, 250], [0, 0, 1]])
    dist = np.array([-0.3, 0.12, 0.0, 0.0, -0.02])
    z = 1400.0
    ground = np.array([[-200.0, -120.0], [0.0, 0.0], [180.0, 90.0], [250.0, -150.0]])
    # camera y points down, ground y up: the ground point (X, Y) sits at camera (X, -Y, z)
    px = _project(k, dist, np.column_stack([ground[:, 0], -ground[:, 1], np.full(4, z)]))
    cal = Calibration(k, dist, (640, 480), mm_per_px=z / 700.0)
    mm = cal.pixels_to_mm(px)
    # the same points up to the choice of origin
    np.testing.assert_allclose(mm - mm[1], ground - ground[1], atol=1e-6)
    # origin: the bottom-left corner, i.e. the undistorted image point (0, H)
    np.testing.assert_allclose(mm[1], [330 * z / 700, (480 - 250) * z / 700], atol=1e-6)
    np.testing.assert_allclose(cal.mm_to_pixels(mm), px, atol=1e-6)
    nan_in = cal.pixels_to_mm(np.array([[np.nan, 3.0], [100.0, 100.0]]))
    assert np.isnan(nan_in[0]).all() and np.isfinite(nan_in[1]).all()


def test_scale_only_calibration():
    cal = Calibration.from_scale(0.5, (640, 480))
    np.testing.assert_allclose(cal.pixels_to_mm([[0.0, 480.0], [10.0, 460.0]]),
                               [[0.0, 0.0], [5.0, 10.0]])
    np.testing.assert_allclose(cal.mm_to_pixels([[5.0, 10.0]]), [[10.0, 460.0]])
    with pytest.raises(InputError, match="no scale"):
        Calibration(np.eye(3), np.zeros(5), (10, 10)).pixels_to_mm([[1.0, 1.0]])


# -- calib.json -----------------------------------------------------------------------------
def test_save_load_round_trip(tmp_path, synthetic_views):
    cal = calibrate(synthetic_views[:4], "chessboard:9x6", square_mm=25)
    cal.mm_per_px = 0.8
    path = tmp_path / "calib.json"
    save_calibration(path, cal)
    assert os.listdir(tmp_path) == ["calib.json"]  # no temporary left behind
    data = json.loads(path.read_text())
    for key in ("camera_matrix", "dist_coeffs", "image_size", "rms_px", "per_view", "mm_per_px"):
        assert key in data
    back = load_calibration(path)
    np.testing.assert_array_equal(back.camera_matrix, cal.camera_matrix)
    np.testing.assert_array_equal(back.dist_coeffs, cal.dist_coeffs)
    assert back.image_size == cal.image_size and back.mm_per_px == 0.8
    assert back.per_view == cal.per_view and back.rms_px == cal.rms_px
    scale_only = tmp_path / "scale.json"
    save_calibration(scale_only, Calibration.from_scale(0.25, (100, 80)))
    assert not load_calibration(scale_only).has_intrinsics


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("image_size"), "missing key"),
    (lambda d: d.update(camera_matrix=[[1, 0], [0, 1]]), "shape"),
    (lambda d: d.update(dist_coeffs=[0.1, 0.2, 0.3]), "dist_coeffs"),
    (lambda d: d.update(mm_per_px=-1), "positive"),
    (lambda d: d.update(image_size=[640.5, 480]), "image_size"),
    (lambda d: d["camera_matrix"][0].__setitem__(0, float("nan")), "NaN"),
])
def test_load_rejects_bad_files(tmp_path, edit, message):
    good = {"camera_matrix": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]],
            "dist_coeffs": [0.0] * 5, "image_size": [640, 480], "mm_per_px": 0.2}
    edit(good)
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(good))
    with pytest.raises(InputError, match=message) as err:
        load_calibration(path)
    assert str(err.value).startswith(str(path))


def test_load_reports_json_line(tmp_path):
    path = tmp_path / "calib.json"
    path.write_text('{\n "camera_matrix": [1,\n }')
    with pytest.raises(InputError, match=r"calib\.json:3: not valid JSON"):
        load_calibration(path)


def test_bad_calibration_inputs(tmp_path, synthetic_views):
    with pytest.raises(ValueError, match="not understood"):
        calibrate(synthetic_views, "checkerboard:9x6", square_mm=25)
    with pytest.raises(ValueError, match="marker_mm"):
        calibrate(synthetic_views, "charuco:5x7", square_mm=25)
    with pytest.raises(InputError, match="found in 2 of 2"):
        calibrate(synthetic_views[:2], "chessboard:9x6", square_mm=25)
    with pytest.raises(InputError, match="no such file"):
        calibrate([tmp_path / "missing.png"], "chessboard:9x6", square_mm=25)
    small = synthetic_views[:3] + [synthetic_views[3][:400]]
    with pytest.raises(InputError, match="image\\[3\\].*first one is 640x480"):
        calibrate(small, "chessboard:9x6", square_mm=25)


# -- the command ------------------------------------------------------------------------------
def test_cli_calibrate_with_scale_image(tmp_path, synthetic_views, capsys):
    from fitlug.cli import main

    folder = tmp_path / "views"
    folder.mkdir()
    for i, img in enumerate(synthetic_views):
        cv2.imwrite(str(folder / f"view{i + 1}.png"), img)
    # the board lying flat in the plane of motion, 500 mm in front of the camera
    flat = render_chessboard(K_TRUE, D_TRUE, *_pose([0, 0, 0], (0, 0, 500)), (640, 480), 9, 6, 25.0)
    cv2.imwrite(str(tmp_path / "flat.png"), flat)
    out = tmp_path / "calib.json"
    code = main(["calibrate", str(folder), "--board", "chessboard:9x6", "--square", "25",
                 "--scale-image", str(tmp_path / "flat.png"), "-o", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "RMS reprojection error" in printed and "scale" in printed
    cal = load_calibration(out)
    assert len(cal.per_view) == 6
    # between 500/605 (rows) and 500/600 (columns)
    assert 500 / 605 * 0.998 < cal.mm_per_px < 500 / 600 * 1.002


def test_cli_reports_bad_arguments_on_one_line(tmp_path, capsys):
    from fitlug.cli import main

    code = main(["calibrate", str(tmp_path), "--board", "chess:9x6", "--square", "25"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--board" in err
    code = main(["calibrate", str(tmp_path / "nothing*.png"), "--board", "chessboard:9x6",
                 "--square", "25", "--scale-points", "1,2,3", "-o", str(tmp_path / "c.json")])
    assert code == 2 and "matches no file" in capsys.readouterr().err
    assert not (tmp_path / "c.json").exists()

"""Files from the field (issue 44): programs' own exports that were refused or misread.

- Tracker's own example car-clip-22-JS.trz (tests/data/trackers/tracker, GPL-3.0, only its
  .trk kept): its XML declares UTF-8 but an author line holds Latin-1 bytes. The values
  checked are read from the XML with regular expressions and mapped by hand.
- Kinovea TXT and Argus xypts files in the programs' exact layouts, small copies of real
  files whose licences are not stated (tests/data/trackers/README.md says which each mirrors).
"""

import math
import os
import re
import zipfile

import numpy as np
import pytest

from fitlug import InputError
from fitlug.cli import main
from fitlug.io import read_any, read_trajectories, read_tracks

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "trackers")
CAR_CLIP = os.path.join(DATA, "tracker", "car-clip-22-JS.trz")


def _car_clip_xml() -> bytes:
    with zipfile.ZipFile(CAR_CLIP) as zf:
        return zf.read("TEST123_Car in a loop with friction.trk")


def test_car_clip_latin1_bytes_under_a_utf8_declaration(tmp_path):
    raw = _car_clip_xml()
    # the file as Tracker 5.1.3 wrote it: UTF-8 declared, Latin-1 bytes on line 11
    assert raw.startswith(b'<?xml version="1.0" encoding="UTF-8"?>')
    assert b"Jal\xf3n" in raw.splitlines()[10]
    with pytest.raises(UnicodeDecodeError):
        raw.decode("utf-8")
    xml = raw.decode("latin-1")
    pat = re.compile(r'name="\[(\d+)\]" type="object">\s*<object class="[^"]*PointMass\$FrameData">'
                     r'\s*<property name="x" type="double">([^<]+)</property>'
                     r'\s*<property name="y" type="double">([^<]+)</property>')
    pts = {int(n): (float(x), float(y)) for n, x, y in pat.findall(xml)}
    assert sorted(pts) == list(range(22))
    tr = read_tracks(CAR_CLIP)
    assert tr.markers == ("masa A",)
    np.testing.assert_array_equal(tr.xy_px[:, 0], np.array([pts[k] for k in range(22)]))
    # frame 21 by hand: origin (615.93, 538.27) px, x axis 1.273 degrees, 5763.38 px/m, y up
    x, y = pts[21]
    a = math.radians(1.273030020056704)
    u = (x - 615.9331476323121) / 5763.384311147731
    w = -(y - 538.2729805013928) / 5763.384311147731
    X, Y = math.cos(a) * u + math.sin(a) * w, -math.sin(a) * u + math.cos(a) * w
    assert tr.xy_mm[21, 0, 0] == pytest.approx(1000 * X, abs=1e-9)  # length_unit m
    assert tr.xy_mm[21, 0, 1] == pytest.approx(1000 * Y, abs=1e-9)
    assert tr.t[21] == pytest.approx(21 * 4.166666666666667e-3, rel=1e-12)  # delta_t in ms
    # the header's source line says how it was read
    out = tmp_path / "car.csv"
    assert main(["import", CAR_CLIP, "--body", "masa A", "-o", str(out), "-q"]) == 0
    rec = read_trajectories(str(out))
    assert rec.meta["source"].startswith("tracker car-clip-22-JS.trz (read as cp1252")
    assert "UTF-8" in rec.meta["source"]
    assert rec.fps == pytest.approx(240.0)


def test_tracker_xml_still_refused_when_broken_in_its_own_encoding(tmp_path):
    broken = _car_clip_xml().replace(b"</object>\n", b"</objet>\n", 1)  # line 26
    p = tmp_path / "broken.trk"
    p.write_bytes(re.sub(rb"[\x80-\xff]", b"o", broken))  # valid UTF-8: nothing else tried
    with pytest.raises(InputError, match=r"broken\.trk:26: malformed Tracker XML: mismatched "
                                         r"tag: line 26, column \d+$"):
        read_any(str(p), body=["masa A"])
    p.write_bytes(broken)  # Latin-1 bytes too: the tag is named, and how it was read
    with pytest.raises(InputError, match=r"broken\.trk:26: malformed Tracker XML: mismatched "
                                         r"tag: line 26, column \d+ \(read as cp1252: the "
                                         r"bytes are not the UTF-8 its XML declares\)$"):
        read_any(str(p), body=["masa A"])


KINOVEA = os.path.join(DATA, "kinovea", "walk_120fps.txt")


def _kinovea_stamps() -> dict[str, list[str]]:
    """Each track's time cells as written (read here with str.split, not by the reader)."""
    out, name = {}, None
    for ln in open(KINOVEA, encoding="utf-8").read().splitlines()[3:]:
        if ln.startswith("# "):
            name = ln[2:]
            out[name] = []
        elif ln.strip():
            out[name].append(ln.split(" ")[0])
    return out


def test_kinovea_rate_from_the_span_not_the_commonest_step(tmp_path):
    stamps = _kinovea_stamps()
    allt = sorted({float(s) for v in stamps.values() for s in v})
    steps = np.round(np.diff(allt), 3)
    assert np.bincount((steps * 1000).astype(int)).argmax() == 8  # the commonest step: 8 ms
    assert len(allt) == 67 and allt[-1] == 0.55  # 66 intervals in 0.550 s: 120 fps
    out = tmp_path / "walk.csv"
    assert main(["import", KINOVEA, "--length-unit", "px", "--mm-per-px", "0.5", "--body",
                 "hanche", "-o", str(out), "-q"]) == 0
    rec = read_trajectories(str(out))
    assert float(rec.meta["fps"]) == pytest.approx(120.0, rel=1e-9)
    # the time column stays as written; the frames count 120ths of a second
    k = rec.markers.index("tarse")
    sel = (rec.marker_index == k) & np.isfinite(rec.x)
    np.testing.assert_array_equal(rec.t[sel], [float(s) for s in stamps["tarse"]])
    np.testing.assert_array_equal(rec.frame[sel], np.arange(55))
    # --fps 120 agrees with the file; 125 (the commonest step's rate) does not
    assert main(["import", KINOVEA, "--length-unit", "px", "--mm-per-px", "0.5", "--body",
                 "hanche", "--fps", "120", "-o", str(out), "-q"]) == 0
    with pytest.raises(InputError, match="matches 125 fps in none"):
        read_any(KINOVEA, length_unit="px", pixels_to_mm=lambda xy: xy, body=["hanche"], fps=125)


def test_kinovea_stamps_without_a_steady_rate_refused(tmp_path):
    text = open(KINOVEA, encoding="utf-8").read().replace("\n0.300 ", "\n0.297 ")
    p = tmp_path / "uneven.txt"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=r"uneven\.txt: the time stamps keep no steady frame rate: "
                                         r"the stamp 0\.297 is 0\.003 off frame 36 at 120 frames"):
        read_tracks(str(p), length_unit="px")


ARGUS = os.path.join(DATA, "argus", "two_tracks-xypts.csv")


def _argus_cells() -> tuple[list[str], list[list[str]]]:
    import csv

    rows = list(csv.reader(open(ARGUS, newline="")))
    return rows[0], rows[1:]


@pytest.mark.parametrize("camera", [None, 2])
def test_argus_xypts_point_per_track_camera_chosen(tmp_path, camera):
    header, rows = _argus_cells()
    cam = camera or 1
    out = tmp_path / "argus.csv"
    args = ["import", ARGUS, "--fps", "100", "--mm-per-px", "0.5", "--body", "Track 1",
            "-o", str(out), "-q"] + (["--camera", str(camera)] if camera else [])
    assert main(args) == 0
    rec = read_trajectories(str(out))
    assert rec.markers == ("Track 1", "Track 2") and rec.roles == ("body", "lug")
    assert rec.meta["source"] == "argus two_tracks-xypts.csv"
    assert rec.meta["camera"] == str(cam) and rec.meta["pixel_origin"] == "bottom-left"
    for m, track in enumerate(rec.markers):
        jx, jy = header.index(f"{track}_cam_{cam}_x"), header.index(f"{track}_cam_{cam}_y")
        sel = rec.marker_index == m
        want_x = np.array([float(r[jx]) for r in rows])
        want_y = np.array([float(r[jy]) for r in rows])
        np.testing.assert_array_equal(rec.frame[sel], np.arange(1, 31))  # rows count from 1
        np.testing.assert_array_equal(rec.x_px[sel], want_x)
        # the origin is the image's bottom-left corner (argus-click): y up already
        np.testing.assert_allclose(rec.x[sel], 0.5 * want_x, rtol=1e-12, equal_nan=True)
        np.testing.assert_allclose(rec.y[sel], 0.5 * want_y, rtol=1e-12, equal_nan=True)
    assert int(np.isfinite(rec.x).sum()) == 2 * (20 if cam == 1 else 12)


def test_argus_and_dltdv_camera_refused_where_absent(tmp_path):
    with pytest.raises(InputError, match=r"two_tracks-xypts\.csv:1: no columns for camera 3 "
                                         r"\(the file's cameras: 1, 2\): give --camera 1 or 2$"):
        read_any(ARGUS, fps=100, camera=3, pixels_to_mm=lambda xy: xy, body=["Track 1"])
    # a line cut at its CR (the file ends lines with CRLF): one line of refusal, no csv.Error
    cut = tmp_path / "cut-xypts.csv"
    cut.write_bytes(open(ARGUS, "rb").read().replace(b"NaN\r\nNaN,NaN", b"NaN\rNaN", 1))
    with pytest.raises(InputError, match=r"cut-xypts\.csv:\d+: row has"):
        read_any(str(cut), fps=100, pixels_to_mm=lambda xy: xy, body=["Track 1"])
    # a DLTdv8 U/V file of two cameras: --camera picks the second (it had no option before)
    p = tmp_path / "run_xypts.csv"
    p.write_text("pt1_cam1_U,pt1_cam1_V,pt1_cam2_U,pt1_cam2_V\n"
                 "1.000000,2.000000,30.000000,40.000000\n"
                 "1.500000,2.500000,31.000000,41.000000\n"
                 "2.000000,3.000000,NaN,NaN\n")
    out = tmp_path / "t.csv"
    assert main(["import", str(p), "--camera", "2", "--fps", "10", "--mm-per-px", "1",
                 "--body", "pt1", "-o", str(out), "-q"]) == 0
    rec = read_trajectories(str(out))
    np.testing.assert_array_equal(rec.x_px, [30.0, 31.0, np.nan])
    assert rec.meta["camera"] == "2"


def _tracker_export(tmp_path, names) -> str:
    """Tracker's "Export Data" text of two tracks (its layout: `#multi:`, the names over
    their columns, `t x y x y`, tab-delimited), 4 frames at 30 fps, metres."""
    rows = ["#multi:", "\t" + "\t\t".join(names), "t\tx\ty\tx\ty"]
    for k in range(4):
        rows.append("\t".join(f"{v:.6g}" for v in (k / 30, 0.01 * k, 0.1, 0.2 + 0.01 * k, 0.05)))
    p = tmp_path / "export.txt"
    p.write_text("\n".join(rows) + "\n")
    return str(p)


def test_roles_of_foreign_names_not_guessed_from_a_first_letter(tmp_path, recwarn):
    path = _tracker_export(tmp_path, ["cart 1", "cart 2"])
    # "cart 1" starts with C but is no C1: not taken for a body marker
    with pytest.raises(InputError, match=r"export\.txt: cannot tell the role of marker 'cart 1': "
                                         r"give --body NAME"):
        read_any(path, length_unit="m")
    rec = read_any(path, length_unit="m", body=["cart 1"])  # told: no guess, no warning
    assert rec.roles == ("body", "lug") and not recwarn.list


def test_roles_guessed_from_the_project_names_said_so(tmp_path, capsys):
    path = _tracker_export(tmp_path, ["C1", "B01"])
    said = (r"export\.txt: roles guessed from the marker names \(body C1; lug B01\): if wrong, "
            r"give --body NAME,\.\.\. \(the others are lugs\) or \[markers\] body = \[\.\.\.\] "
            r"in rig\.toml$")
    with pytest.warns(UserWarning, match=said):
        rec = read_any(path, length_unit="m")
    assert rec.roles == ("body", "lug")
    capsys.readouterr()
    # the command says it too, as its one-line warning on the terminal
    assert main(["import", path, "--length-unit", "m", "-o", str(tmp_path / "t.csv")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("fit-lug: warning:") and re.search(said[:-1], err), err


def test_kinovea_pixels_world_space_y_up_image_space_y_down(tmp_path):
    """Kinovea's source (DrawingTrack.CollectMeasuredData, CalibratorPlane.GridToWorldWithOffset):
    the default export is its world space, y up, origin at the image centre without a
    calibration; the image-space preference writes image pixels, y down."""
    stamps = _kinovea_stamps()
    row = open(KINOVEA, encoding="utf-8").read().splitlines()[4]  # hanche at t = 0.000
    x, y = (float(c.replace(",", ".")) for c in row.split(" ")[1:3])
    assert row.startswith("0.000 ") and len(stamps["hanche"]) == 67
    # image pixels (y down) to mm (y up) at 0.5 mm/px, as --mm-per-px 0.5 maps them
    to_mm = lambda p: np.stack([0.5 * p[..., 0], -0.5 * p[..., 1]], axis=-1)  # noqa: E731
    opts = dict(length_unit="px", pixels_to_mm=to_mm, body=["hanche"])
    rec = read_any(KINOVEA, **opts)
    assert rec.meta["pixel_origin"] == "image centre, y up (world space)"
    assert (rec.x[0], rec.y[0]) == (0.5 * x, 0.5 * y)  # y up as written
    # negative values: world space, never Kinovea's image space
    with pytest.raises(InputError, match=r"walk_120fps\.txt: negative pixel coordinates"):
        read_any(KINOVEA, y_origin="top", **opts)
    # an image-space export (all positive): y down, turned up
    text = open(KINOVEA, encoding="utf-8").read().replace(" -", " ")
    p = tmp_path / "image_space.txt"
    p.write_text(text, encoding="utf-8")
    up, down = read_any(str(p), **opts), read_any(str(p), y_origin="top", **opts)
    assert down.meta["pixel_origin"] == "top-left (image space)"
    np.testing.assert_array_equal(down.y, -up.y)
    np.testing.assert_array_equal(down.x, up.x)

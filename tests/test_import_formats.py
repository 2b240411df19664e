"""Each tracker format end to end (issue 29): a simulated recording exported in that format
(tests/trackers_export.py: pixels and the format's own conventions) and read back by
`fit-lug FILE`'s path gives the canonical twin's positions and the same fitted slip, within
the slip's error; then the formats' documented traps and a broken file of each format.
"""

import os

import numpy as np
import pytest

import trackers_export as ex
from fitlug import InputError
from fitlug.cli import main
from fitlug.fit import fit
from fitlug.io import Recording, detect_format, read_any
from fitlug.sim import Scenario, simulate

SCENARIO = Scenario(duration_s=2.5, travel_mm=250.0, rest_s=0.25, ramp_s=0.7)
BODY = ["C1", "C2"]


@pytest.fixture(scope="module")
def sim():
    return simulate(SCENARIO, 0)[0]


@pytest.fixture(scope="module")
def twin(sim):
    return sim, fit(sim).quantities["slip"]


def _px_to_mm(xy):  # the scale-only mapping of `fit-lug track`, origin at the image's bottom
    return np.stack([ex.S * xy[..., 0], ex.S * (ex.H - xy[..., 1])], axis=-1)


def _write(tmp_path, name, text):
    p = tmp_path / name
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    return str(p)


def _files(rec, tmp_path):
    """(file, format, read_any options, tolerance in mm) for every format."""
    ids = [10 + 3 * k for k in range(rec.n_markers)]
    trz = tmp_path / "run.trz"
    ex.tracker_trz(rec, trz)
    px = {"pixels_to_mm": _px_to_mm, "image_height": ex.H}
    return [
        (_write(tmp_path, "run.trk", ex.tracker_trk(rec)), "tracker", {}, 1e-9),
        (str(trz), "tracker-trz", {}, 1e-9),
        (_write(tmp_path, "export.txt", ex.tracker_text(rec)), "tracker-text",
         {"length_unit": "m"}, 1e-7),
        (_write(tmp_path, "xypts.csv", ex.dltdv(rec)), "dltdv", {"fps": 100, **px}, 1e-7),
        (_write(tmp_path, "old_xypts.csv", ex.dltdv(rec, "XY7")), "dltdv",
         {"fps": 100, "y_origin": "bottom", "body": ["pt11", "pt12"], **px}, 1e-7),
        (_write(tmp_path, "kinovea.csv", ex.kinovea_csv(rec)), "kinovea-csv",
         {"length_unit": "px", **px}, 2e-5),
        (_write(tmp_path, "kinovea.txt", ex.kinovea_txt(rec)), "kinovea-txt",
         {"length_unit": "cm"}, 1e-6),
        (_write(tmp_path, "dlc.csv", ex.dlc_csv(rec)), "deeplabcut", {"fps": 100, **px}, 1e-9),
        (_write(tmp_path, "ma_dlc.csv", ex.dlc_csv(rec, individuals=True)), "deeplabcut",
         {"fps": 100, **px}, 1e-9),
        (_write(tmp_path, "linked.csv", ex.trackpy_csv(rec, ids)), "trackpy",
         {"fps": 100, "body": [str(i) for i in ids[-2:]], **px}, 1e-9),
    ]


def _same_positions(got: Recording, want: Recording, tol: float):
    """The same samples up to a translation (the fit's offsets absorb where the origin is)."""
    assert got.n_markers == want.n_markers
    t = np.unique(want.t)
    np.testing.assert_allclose(np.unique(got.t), t, atol=1e-9)
    shift = None
    for k, m in enumerate(want.markers):
        w = want.marker_index == k
        g = got.marker_index == (got.markers.index(m) if m in got.markers else k)
        assert got.roles[got.marker_index[g][0]] == want.roles[k]
        gx, gy = got.x[g], got.y[g]
        np.testing.assert_array_equal(np.isfinite(gx), np.isfinite(want.x[w]))
        d = np.stack([gx - want.x[w], gy - want.y[w]])[:, np.isfinite(gx)]
        shift = d[:, 0] if shift is None else shift
        np.testing.assert_allclose(d - shift[:, None], 0, atol=tol)
    return shift


def test_each_format_gives_the_canonical_twins_slip(twin, tmp_path):
    rec, slip = twin
    for path, fmt, opts, tol in _files(rec, tmp_path):
        assert detect_format(path) == fmt, path
        got = read_any(path, **{"body": BODY, **opts})
        _same_positions(got, rec, tol)
        assert got.meta["source"].startswith(fmt.split("-")[0])
        res = fit(got)
        s = res.quantities["slip"]
        print(f"{fmt:13s} slip {s.value:.9f} (twin {slip.value:.9f} +- {slip.std:.2g})")
        assert abs(s.value - slip.value) < 0.05 * slip.std, fmt


def test_deeplabcut_h5_and_dataframes(sim, tmp_path):
    pd = pytest.importorskip("pandas")
    rec = sim
    df = ex.dlc_dataframe(rec)
    got = Recording.from_dataframe(df, fps=100, mm_per_px=ex.S, body=BODY)
    _same_positions(got, rec, 1e-9)
    head, rows = ex.trackpy_rows(rec, list(range(rec.n_markers)))
    tp = pd.DataFrame(rows, columns=head)
    got = Recording.from_dataframe(tp, fps=100, mm_per_px=ex.S, body=["10", "11"])
    _same_positions(got, rec, 1e-9)
    with pytest.raises(InputError, match="no time stamps"):
        Recording.from_dataframe(tp, mm_per_px=ex.S, body=["10", "11"])
    pytest.importorskip("tables")
    h5 = tmp_path / "dlc.h5"
    df.to_hdf(h5, key="df_with_missing", format="table", mode="w")  # as DeepLabCut saves it
    assert detect_format(h5) == "deeplabcut-h5"
    _same_positions(read_any(h5, fps=100, body=BODY, pixels_to_mm=_px_to_mm), rec, 1e-9)


def test_cli_import_and_fit_lug_file(twin, tmp_path, capsys):
    rec, slip = twin
    trk = _write(tmp_path, "car.trk", ex.tracker_trk(rec))
    out = tmp_path / "trajectories.csv"
    assert main(["import", trk, "-o", str(out), "--body", "C1,C2", "-q"]) == 0
    text = out.read_text()
    assert text.startswith("# source: tracker car.trk\n")
    from fitlug.io import read_trajectories

    _same_positions(read_trajectories(out), rec, 1e-9)
    # DLTdv pixels through --mm-per-px (the code of fit-lug track); no fps: refused
    xy = _write(tmp_path, "xypts.csv", ex.dltdv(rec))
    assert main(["import", xy, "-o", str(tmp_path / "x.csv"), "--mm-per-px", "0.05"]) == 2
    assert "no time stamps: give the frame rate" in capsys.readouterr().err
    assert main(["import", xy, "-o", str(tmp_path / "x.csv"), "--mm-per-px", "0.05",
                 "--fps", "100", "-q"]) == 0
    assert not os.path.exists(tmp_path / "fits")
    # fit-lug FILE converts on the way in
    assert main([xy, "--fps", "100", "--mm-per-px", "0.05", "--no-mcmc", "--no-explain",
                 "--no-report", "-q", "--out", str(tmp_path / "fit")]) == 0
    import json

    doc = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert abs(doc["slip"]["value"] - slip.value) < 0.05 * slip.std


@pytest.mark.parametrize("name, text, opts, problem", [
    ("bad.trk", '<?xml version="1.0"?>\n<object class="org.opensourcephysics.cabrillo.tracker.'
     'TrackerPanel">\n<property name="tracks" type="collection">\n</object>\n', {},
     "malformed Tracker XML"),
    ("tv.trk", "TRACK\0\0\0binary", {}, "TrackVis tractography"),
    ("xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1.0,2.0\n", {"fps": 100}, "--y-origin bottom|top"),
    ("xypts.csv", "pt1_cam1_U,pt1_cam1_V\n1.0,2.0\n1.5,abc\n", {"fps": 100},
     "xypts.csv:3: column pt1_cam1_V: 'abc' is not a number"),
    ("k.csv", '"Time","A/0/X","A/0/Y"\n"0.0","1","2"\n', {}, "give --length-unit"),
    ("k.txt", "#Kinovea Trajectory data export\n#T X Y\n\n# A\n0,0 1,0\n", {"length_unit": "mm"},
     "k.txt:5: expected 't x y'"),
    ("dlc.csv", "scorer,s,s\nbodyparts,a,a\ncoords,x,y\n0,1.0,x2\n", {"fps": 1},
     "dlc.csv:4: column a/y: 'x2' is not a number"),
    ("tp.csv", "frame,x,y,mass\n0,1,2,3\n", {"fps": 1}, "not linked (run trackpy.link first)"),
    ("t.txt", "mass_A\nt\tx\ty\n0.0\t1.0\t2.0\n0.1\t1.1\t2.1\n", {}, "give --length-unit"),
    ("z.zip", None, {}, "a zip file without a Tracker .trk"),
    ("other.csv", "a,b,c\n1,2,3\n", {}, "known formats are fitlug, tracker"),
])
def test_broken_files_get_one_line_naming_file_place_problem(tmp_path, name, text, opts, problem):
    path = tmp_path / name
    if text is None:
        import zipfile

        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("readme.txt", "x")
    else:
        path.write_text(text)
    with pytest.raises(InputError) as err:
        read_any(path, **opts)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and problem in msg, msg


def _trk(coords: str, points: str, unit="cm") -> str:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<object class="org.opensourcephysics.cabrillo.tracker.TrackerPanel">\n'
            f'<property name="coords" type="object">{coords}</property>\n'
            f'<property name="length_unit" type="string">{unit}</property>\n'
            '<property name="tracks" type="collection" class="java.util.ArrayList">'
            '<property name="item" type="object">'
            '<object class="org.opensourcephysics.cabrillo.tracker.PointMass">'
            '<property name="name" type="string">C1</property>'
            f'<property name="framedata" type="array">{points}</property>'
            '</object></property></property></object>\n')


def _fd(k, **v):
    cls = "PointMass$FrameData" if "x" in v else "ImageCoordSystem$FrameData"
    props = "".join(f'<property name="{n}" type="double">{x!r}</property>' for n, x in v.items())
    return f'<property name="[{k}]" type="object"><object class="{cls}">{props}</object></property>'


def test_tracker_key_frames_hold_until_the_next(tmp_path):
    """A coordinate system whose origin moves at key frame 3 and whose angle is fixed:
    frames 0-2 use key frame 0's origin, frames 3-5 key frame 3's (OSP's setOriginXY with
    updateToKeyFrames); no delta_t: the time needs --fps."""
    frames = "".join([_fd(0, xorigin=100.0, yorigin=200.0, angle=90.0, xscale=10.0, yscale=10.0),
                      _fd(3, xorigin=110.0, yorigin=190.0, angle=90.0, xscale=10.0, yscale=10.0)])
    coords = ('<object class="org.opensourcephysics.media.core.ImageCoordSystem">'
              '<property name="fixedorigin" type="boolean">false</property>'
              '<property name="fixedangle" type="boolean">true</property>'
              '<property name="fixedscale" type="boolean">true</property>'
              f'<property name="framedata" type="array">{frames}</property></object>')
    pts = "".join(_fd(k, x=120.0, y=150.0) for k in range(6))
    path = _write(tmp_path, "keys.trk", _trk(coords, pts))
    from fitlug.io import read_tracks

    tr = read_tracks(path)
    # angle 90 deg: the world x axis points up the image. By hand: u = (x - x0)/s,
    # w = -(y - y0)/s, X = cos a u + sin a w = w, Y = -sin a u + cos a w = -u; cm -> mm
    for k, (x0, y0) in enumerate([(100, 200)] * 3 + [(110, 190)] * 3):
        u, w = (120 - x0) / 10, -(150 - y0) / 10
        np.testing.assert_allclose(tr.xy_mm[k, 0], [10 * w, -10 * u], atol=1e-12)
    assert tr.t is None
    with pytest.raises(InputError, match="no time stamps"):
        read_any(path)
    assert read_any(path, fps=50).fps == pytest.approx(50)


def test_tracker_text_one_track_and_kinovea_milliseconds(tmp_path):
    # Tracker, one track: its name (spaces as '_'), then t x y; space-delimited
    p = _write(tmp_path, "one.txt", "masa_A\nt x y\n0.0 0.10 0.20\n0.01 0.11 0.21\n"
                                    "0.02  \n0.03 0.13 0.23\n")
    assert detect_format(p) == "tracker-text"
    rec = read_any(p, length_unit="m", body=["masa_A"])
    assert rec.markers == ("masa_A",) and rec.meta["fps"] == "100"
    np.testing.assert_allclose(rec.x[rec.valid], [100, 110, 130])
    # Kinovea CSV whose Time column is in ms (a user preference): --fps tells it
    p = _write(tmp_path, "ms.csv", '"Time","C1/0/X","C1/0/Y"\n"0","1.5","2"\n"10","1.6","2"\n'
                                   '"20","",""\n"30","1.8","2.1"\n')
    rec = read_any(p, length_unit="mm", fps=100)
    assert rec.meta["time_unit"] == "ms"
    np.testing.assert_allclose(rec.t, [0, 0.01, 0.02, 0.03])
    assert np.isnan(rec.x[2]) and rec.x[3] == pytest.approx(1.8)
    with pytest.raises(InputError, match="matches 25 fps in none of s, ms"):
        read_any(p, length_unit="mm", fps=25)


def test_a_wrong_pixel_origin_is_caught_by_the_physics(sim, tmp_path):
    """A DLTdv7 file (origin bottom-left) read as DLTdv8 (top-left) turns the track upside
    down: the lugs would run fastest along the bottom, which a crawler track never does."""
    rec = sim
    path = _write(tmp_path, "old_xypts.csv", ex.dltdv(rec, "XY7"))
    opts = {"fps": 100, "body": ["pt11", "pt12"], "pixels_to_mm": _px_to_mm}
    with pytest.warns(UserWarning, match="looks upside down"):
        read_any(path, y_origin="top", **opts)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_any(path, y_origin="bottom", **opts)

"""fitlug.io: trajectories.csv, rig.toml and JSON files against the DATA.md contract."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from fitlug._errors import InputError
from fitlug.io import (Recording, Rig, atomic_path, check_enough_samples, find_rig, read_json,
                       read_rig, read_trajectories, write_json, write_rig, write_trajectories)
from fitlug.io import _write_trajectories

# The example of DATA.md, verbatim.
DATA_MD_CSV = """\
# any number of comment lines first; `# key: value` lines are metadata (fps, source, units)
time_s,marker,role,x_mm,y_mm
0.00,C1,body,-35.112,71.004
0.00,B03,lug,12.870,-4.020
"""
DATA_MD_RIG = """\
[track]
load_bearing_length_mm = 127.0   # L
lugs_in_contact = 8              # n
lug_pitch_mm = 18.36             # p, optional
[vehicle]
mass_kg = 2.0                    # mass carried by this track, optional
[markers]                        # optional: roles by name, for wide files
body = ["C1", "C2"]
"""


def _write(tmp_path, text, name="traj.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return str(path)


def _synthetic(seed=0, n_frames=50, with_optional=True):
    """A recording with known values, sorted the way the reader sorts."""
    rng = np.random.default_rng(seed)
    markers, roles = ("C1", "C2", "B01", "B02", "L7"), ("body", "body", "lug", "lug", "lug")
    time = np.arange(n_frames) / 2000.0 + rng.uniform(0, 1e-7, n_frames)
    m = len(markers)
    x = rng.normal(0, 100, m * n_frames)
    y = rng.normal(0, 50, m * n_frames)
    x[[3, 77]] = np.nan
    y[[3, 150]] = np.nan
    optional = {}
    if with_optional:
        optional = dict(sigma=rng.uniform(0.001, 0.01, m * n_frames),
                        frame=np.tile(np.arange(n_frames) + 100, m),
                        x_px=rng.uniform(0, 1024, m * n_frames),
                        y_px=rng.uniform(0, 512, m * n_frames),
                        quality=rng.uniform(0, 1, m * n_frames))
        optional["x_px"][3] = np.nan
    return Recording(markers=markers, roles=roles, t=np.tile(time, m),
                     marker_index=np.repeat(np.arange(m), n_frames), x=x, y=y,
                     meta={"fps": "2000", "source": "synthetic"}, **optional)


# -- reading the contract's example -------------------------------------------------------

def test_data_md_example_parses(tmp_path):
    rec = read_trajectories(_write(tmp_path, DATA_MD_CSV))
    assert rec.markers == ("C1", "B03")
    assert rec.roles == ("body", "lug")
    assert rec.t.tolist() == [0.0, 0.0]
    assert rec.x.tolist() == [-35.112, 12.870]
    assert rec.y.tolist() == [71.004, -4.020]
    assert rec.marker_index.dtype == np.int64 and rec.marker_index.tolist() == [0, 1]
    assert rec.sigma is None and rec.frame is None and rec.quality is None
    assert rec.role_of("B03") == "lug"
    assert rec.select("body").tolist() == [0] and rec.select("lug").tolist() == [1]
    assert rec.meta == {}  # that comment line has no `key: value` form
    assert rec.path.endswith("traj.csv")


def test_metadata_lines_and_fps(tmp_path):
    text = "# fps: 4000\n# source: cam 2\n# units: mm\n# just a remark\n" + DATA_MD_CSV
    rec = read_trajectories(_write(tmp_path, text))
    assert rec.meta == {"fps": "4000", "source": "cam 2", "units": "mm"}
    assert rec.fps == 4000.0


def test_fps_from_frame_times_when_no_metadata(tmp_path):
    rows = "".join(f"{i / 500},C1,body,{i},0\n" for i in range(7))
    rec = read_trajectories(_write(tmp_path, "time_s,marker,role,x_mm,y_mm\n" + rows))
    assert rec.fps == pytest.approx(500.0, rel=1e-9)
    assert rec.times().tolist() == [i / 500 for i in range(7)]


# -- round trips ----------------------------------------------------------------------------

def test_long_round_trip_is_exact(tmp_path):
    rec = _synthetic()
    path = str(tmp_path / "out.csv")
    write_trajectories(path, rec)
    back = read_trajectories(path)
    assert back == rec
    assert np.array_equal(back.x, rec.x, equal_nan=True)  # == is exact, check it is
    with open(path, encoding="utf-8") as fh:
        text = fh.read().splitlines()
    assert text[:2] == ["# fps: 2000", "# source: synthetic"]
    assert text[2] == "time_s,marker,role,x_mm,y_mm,frame,sigma_mm,x_px,y_px,quality"
    # frame by frame, and NaN as an empty field
    assert [line.split(",")[1] for line in text[3:8]] == ["C1", "C2", "B01", "B02", "L7"]
    assert text[3 + 5 * 3].split(",")[3:5] == ["", ""]  # sample 3 is C1 in frame 3


def test_round_trip_notices_a_change(tmp_path):
    rec = _synthetic(with_optional=False)
    path = str(tmp_path / "out.csv")
    write_trajectories(path, rec, meta={"units": "mm"})
    back = read_trajectories(path)
    assert back.meta == {"fps": "2000", "source": "synthetic", "units": "mm"}
    assert back == rec.with_(meta={**rec.meta, "units": "mm"})
    x = back.x.copy()
    x[10] = np.nextafter(x[10], np.inf)
    assert back.with_(x=x) != back


def test_round_trip_with_fixed_precision_keeps_micrometres(tmp_path):
    rec = _synthetic(with_optional=False)
    path = str(tmp_path / "out.csv")
    write_trajectories(path, rec, precision=9)
    back = read_trajectories(path)
    ok = rec.valid
    assert np.array_equal(back.valid, ok)
    assert np.max(np.abs(back.x[ok] - rec.x[ok])) < 1e-4  # |x| < 1000 mm -> 9 digits
    assert np.all(np.abs(back.t - rec.t) <= 5e-9 * np.abs(rec.t))  # 9 significant digits


def test_marker_order_survives_when_a_marker_starts_late(tmp_path):
    # marker 0 is first seen after marker 1: the writer must not reorder the markers
    rec = Recording(markers=("C1", "B01"), roles=("body", "lug"), t=[0.5, 0.6, 0.0, 0.1],
                    marker_index=[0, 0, 1, 1], x=[1.0, 2, 3, 4], y=[5.0, 6, 7, 8])
    path = str(tmp_path / "late.csv")
    write_trajectories(path, rec)
    assert read_trajectories(path) == rec


WIDE = """\
# exported by a motion-analysis program
frame,time_s,C1_x_mm,C1_y_mm,B03_x_mm,B03_y_mm,COG5_X_MM,COG5_Y_MM,comment
10,0.000,-35.112,71.004,12.870,-4.020,1.5,2.5,a
11,0.001,-35.100,71.010,,,1.6,2.6,b
12,0.002,-35.088,71.016,12.900,-4.100,1.7,nan,c
"""


def test_wide_form(tmp_path):
    rec = read_trajectories(_write(tmp_path, WIDE))
    assert rec.markers == ("C1", "B03", "COG5")
    assert rec.roles == ("body", "lug", "lug")  # COG before C, B -> lug
    b03 = rec.marker_index == 1
    assert rec.t[b03].tolist() == [0.0, 0.001, 0.002]
    assert rec.x[b03][[0, 2]].tolist() == [12.870, 12.900]
    assert np.isnan(rec.x[b03][1]) and np.isnan(rec.y[b03][1])
    assert rec.frame[b03].tolist() == [10, 11, 12]
    assert np.count_nonzero(~rec.valid) == 2
    path = str(tmp_path / "long.csv")
    write_trajectories(path, rec)
    assert read_trajectories(path) == rec


def test_wide_roles_from_rig_and_names(tmp_path):
    text = "time_s,QS1_x_mm,QS1_y_mm,body2_x_mm,body2_y_mm,lugA_x_mm,lugA_y_mm,P9_x_mm,P9_y_mm\n" \
           "0,1,2,3,4,5,6,7,8\n"
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as err:
        read_trajectories(path)
    assert "P9" in str(err.value) and "rig.toml" in str(err.value) and ":1:" in str(err.value)
    rec = read_trajectories(path, rig=Rig(lug_markers=("P9", "QS1")))
    assert rec.roles == ("lug", "body", "lug", "lug")  # the rig wins over the name


def test_rows_in_any_order(tmp_path):
    rec = _synthetic(seed=3, n_frames=40, with_optional=False)
    header = "time_s,marker,role,x_mm,y_mm,extra_column\n"

    def row(i):
        fmt = lambda v: "" if np.isnan(v) else repr(float(v))  # noqa: E731
        k = rec.marker_index[i]
        return f"{float(rec.t[i])!r},{rec.markers[k]},{rec.roles[k]},{fmt(rec.x[i])},{fmt(rec.y[i])},z\n"

    by_marker = range(rec.n_samples)
    by_frame = np.lexsort((rec.marker_index, rec.t))
    a = read_trajectories(_write(tmp_path, header + "".join(map(row, by_marker)), "a.csv"))
    b = read_trajectories(_write(tmp_path, header + "".join(map(row, by_frame)), "b.csv"))
    assert a == b == rec.with_(meta={})
    # columns in another order, roles in capitals
    text = "y_mm,role,marker,x_mm,time_s\n4,Lug,B1,3,0.1\n2,BODY,C1,1,0.0\n6,body,C1,5,0.1\n" \
           "8,lug,B1,7,0.2\n"
    c = read_trajectories(_write(tmp_path, text, "c.csv"))
    assert c.markers == ("B1", "C1") and c.roles == ("lug", "body")
    assert c.t.tolist() == [0.1, 0.2, 0.0, 0.1]  # sorted by (marker, time)
    assert c.x.tolist() == [3.0, 7.0, 1.0, 5.0] and c.y.tolist() == [4.0, 8.0, 2.0, 6.0]


def test_missing_values_become_nan(tmp_path):
    text = "time_s,marker,role,x_mm,y_mm,sigma_mm\n" \
           "0,C1,body, ,1,0.002\n0.1,C1,body,NaN,nan,\n0.2,C1,body,3, 4 ,0.003\n"
    rec = read_trajectories(_write(tmp_path, text))
    assert np.isnan(rec.x[:2]).all() and rec.x[2] == 3.0
    assert np.isnan(rec.y[1]) and rec.y[[0, 2]].tolist() == [1.0, 4.0]
    assert rec.valid.tolist() == [False, False, True]
    assert np.isnan(rec.sigma[1])
    check_enough_samples(rec, 1)
    with pytest.raises(InputError, match=r"traj\.csv: fewer valid samples \(1\) than "
                                         r"parameters \(2\)"):
        check_enough_samples(rec, 2)


# -- bad input: file name, line number and problem in one line -------------------------------

H = "time_s,marker,role,x_mm,y_mm\n"
HF = "time_s,marker,role,x_mm,y_mm,frame\n"
BAD = [
    ("", None, "empty file"),
    ("# only a comment\n\n", None, "empty file"),
    (H, 1, "no samples"),
    ("time_s,marker,x_mm,y_mm\n0,C1,1,2\n", 1, "missing required column 'role'"),
    ("time_s,x,y\n0,1,2\n", 1, "missing required column 'marker'"),
    ("# c\n" + H + "0,C1,body,1,2\n0.1,C1,body,1.2.3,2\n", 4, "text in number column x_mm: '1.2.3'"),
    (H + "zero,C1,body,1,2\n", 2, "text in number column time_s: 'zero'"),
    (H + "0,C1,body,1,2\n0.1,B1,wheel,1,2\n", 3, "role must be 'body' or 'lug', got 'wheel'"),
    (H + "0,C1,body,1,2\n0.1,C1,lug,1,2\n", 3, "marker C1 changes role from body to lug"),
    # rows in any order: time goes backwards only against the frame numbers
    (HF + "0.1,C1,body,1,2,6\n0,B1,lug,1,2,5\n0.0,C1,body,1,2,7\n", 4,
     "time going backwards for marker C1: frame 7 at 0.0 s here, frame 6 at 0.1 s on line 2"),
    (HF + "0.1,C1,body,1,2,6\n0.2,C1,body,1,2,6\n", 3,
     "marker C1: frame 6 has two time stamps, 0.2 s here and 0.1 s on line 2"),
    (HF + "0.1,C1,body,1,2,6\n0.2,B1,lug,1,2,6\n", 3,
     "frame 6 has two time stamps: 0.2 s here and 0.1 s on line 2"),
    (H + "0.1,C1,body,1,2\n0.1,C1,body,1,2.5\n", 3,
     "marker C1 appears twice at time_s = 0.1 with different values (also on line 2)"),
    (HF + "0,C1,body,1,2,9223372036854775808\n", 2,
     "frame number 9223372036854775808 is out of range"),
    (HF + "0,C1,body,1,2,1e19\n", 2, "frame number 1e19 is out of range"),
    (HF + "0,C1,body,1,2,-1E19\n", 2, "frame number -1E19 is out of range"),
    ("time_s;marker;role;x_mm;y_mm\n0;C1;body;1;2\n", 1, "the separator looks wrong: ';'"),
    ("time_s\tmarker\trole\tx_mm\ty_mm\n0\tC1\tbody\t1\t2\n", 1,
     "the separator looks wrong: tab"),
    ("time_s marker  role x_mm y_mm\n0 C1 body 1 2\n", 1, "the separator looks wrong: spaces"),
    (H + "0;C1;body;1;2\n", 2, "the separator looks wrong: ';'"),
    (H + "0,C1,body,1,2\n,C1,body,1,2\n", 3, "empty value in column time_s"),
    (H + "0,C1,body,1,2\nnan,C1,body,1,2\n", 3, "NaN value in column time_s"),
    (H + "0,C1,body,1,2\n0.1,C1,body,inf,2\n", 3, "infinite value in column x_mm: 'inf'"),
    (H + "0,C1,body,1\n", 2, "row has 4 fields, the header has 5"),
    (H + "0,,body,1,2\n", 2, "empty marker id"),
    ("time_s,marker,role,x_mm,y_mm,frame\n0,C1,body,1,2,1.5\n", 2, "column frame must hold integers"),
    ("time_s,marker,role,x_mm,y_mm,sigma_mm\n0,C1,body,1,2,-0.1\n", 2, "sigma_mm must be > 0"),
    ("# fps: fast\n" + H + "0,C1,body,1,2\n", 1, "metadata fps must be a number > 0"),
    ("time_s,C1_x_mm,C1_y_mm,B1_x_mm\n0,1,2,3\n", 1, "column B1_x_mm has no partner column B1_y_mm"),
    ("time_s,C1_x_mm,C1_y_mm\n0,1,2\n0,1,3\n", 3, "time_s = 0.0 appears twice with different"),
    ("time_s,C1_x_mm,C1_y_mm\n0,1,2\n0.1,1,x\n", 3, "text in number column C1_y_mm: 'x'"),
    ("C1_x_mm,C1_y_mm\n1,2\n", 1, "missing required column 'time_s'"),
    (H.replace("role", "marker"), 1, "column 'marker' appears twice"),
]


@pytest.mark.parametrize("text,line,problem", BAD, ids=[b[2][:40] for b in BAD])
def test_bad_input_names_file_line_and_problem(tmp_path, text, line, problem):
    path = _write(tmp_path, text, "bad_input.csv")
    with pytest.raises(InputError) as err:
        read_trajectories(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(path + (f":{line}:" if line else ":"))
    assert problem in message
    assert err.value.line == line


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(InputError, match=r"nowhere\.csv: file not found"):
        read_trajectories(tmp_path / "nowhere.csv")
    with pytest.raises(InputError, match="is a directory"):
        read_trajectories(tmp_path)
    path = tmp_path / "latin1.csv"
    path.write_bytes(H.encode() + b"0,C\xe91,body,1,2\n")
    with pytest.raises(InputError, match=r"latin1\.csv:2: not UTF-8"):
        read_trajectories(path)


def test_writer_refuses_what_would_not_read_back(tmp_path):
    rec = Recording(markers=("C1",), roles=("body",), t=[0.0, 0.0], marker_index=[0, 0],
                    x=[1.0, 2.0], y=[1.0, 2.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        write_trajectories(tmp_path / "dup.csv", rec)
    with pytest.raises(ValueError, match="cannot be written"):
        write_trajectories(tmp_path / "m.csv", rec.with_(t=[0.0, 1.0]), meta={"a b": "c"})
    assert not os.listdir(tmp_path)


def test_recording_validates_its_arrays():
    with pytest.raises(ValueError, match="role"):
        Recording(markers=("A",), roles=("wheel",), t=[0.0], marker_index=[0], x=[0.0], y=[0.0])
    with pytest.raises(ValueError, match="shape"):
        Recording(markers=("A",), roles=("lug",), t=[0.0, 1.0], marker_index=[0], x=[0.0],
                  y=[0.0])
    with pytest.raises(ValueError, match="out of range"):
        Recording(markers=("A",), roles=("lug",), t=[0.0], marker_index=[1], x=[0.0], y=[0.0])
    rec = Recording(markers=("A",), roles=("lug",), t=[0.0], marker_index=[0], x=[0.0], y=[0.0])
    with pytest.raises(KeyError, match="no marker 'Z'"):
        rec.role_of("Z")
    assert rec.fps is None


# -- atomic writing -----------------------------------------------------------------------

def test_failed_write_leaves_no_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    path = tmp_path / "traj.csv"
    rec = _synthetic(with_optional=False)

    class Failing:
        def __init__(self, fh, **kw):
            self.fh = fh

        def writerow(self, row):
            self.fh.write(",".join(row) + "\n")

        def writerows(self, rows):
            for i, row in enumerate(rows):
                if i == 10:
                    raise OSError("disk full")
                self.writerow(row)

    monkeypatch.setattr(_write_trajectories.csv, "writer", Failing)
    with pytest.raises(OSError, match="disk full"):
        write_trajectories(path, rec)
    assert os.listdir(tmp_path) == []  # neither the file nor a temporary left behind

    path.write_text("old contents\n")
    with pytest.raises(OSError, match="disk full"):
        write_trajectories(path, rec)
    assert path.read_text() == "old contents\n"
    assert os.listdir(tmp_path) == ["traj.csv"]


def test_atomic_path_on_exception(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            with open(tmp, "w") as fh:
                fh.write("half")
            raise RuntimeError("mid-way")
    assert os.listdir(tmp_path) == []


# -- rig.toml -------------------------------------------------------------------------------

def test_rig_defaults_are_the_reference_robot():
    rig = Rig()
    assert (rig.load_bearing_length_mm, rig.lugs_in_contact) == (127.0, 8)  # MODEL.md section 2
    assert rig.lug_pitch_mm is None and rig.mass_kg is None and rig.fps is None
    assert Rig.reference() == Rig(lug_pitch_mm=18.36)


def test_data_md_rig_example(tmp_path):
    rig = read_rig(_write(tmp_path, DATA_MD_RIG, "rig.toml"))
    assert rig == Rig(load_bearing_length_mm=127.0, lugs_in_contact=8, lug_pitch_mm=18.36,
                      mass_kg=2.0, body_markers=("C1", "C2"))
    assert rig.extra == {}
    assert isinstance(rig.lugs_in_contact, int)


def test_rig_round_trip_keeps_extra_tables_and_writes_only_set_keys(tmp_path):
    text = 'note = "bench 3"\n' + DATA_MD_RIG + 'lug = ["B1"]\n[camera]\nfps = 2000\n' \
           'model = "Phantom v9.1"\n[lighting]\nlamps = 2\ncolour = {r = 1, g = 0.5}\n'
    rig = read_rig(_write(tmp_path, text, "rig.toml"))
    assert rig.fps == 2000.0 and rig.lug_markers == ("B1",)
    assert rig.extra == {"note": "bench 3", "camera": {"model": "Phantom v9.1"},
                         "lighting": {"lamps": 2, "colour": {"r": 1, "g": 0.5}}}
    out = tmp_path / "out.toml"
    write_rig(out, rig)
    assert read_rig(out) == rig
    write_rig(out, Rig())
    written = out.read_text()
    assert "[track]" in written and "lug_pitch_mm" not in written and "[vehicle]" not in written
    assert read_rig(out) == Rig()


def test_rig_unknown_key_in_known_table_warns(tmp_path):
    path = _write(tmp_path, "[track]\ncolour = \"red\"\n", "rig.toml")
    with pytest.warns(UserWarning, match=r"rig\.toml:2: \[track\] unknown key .colour."):
        rig = read_rig(path)
    assert rig.lugs_in_contact == 8 and rig.extra == {"track": {"colour": "red"}}


RIG_BAD = [
    ("[track]\nlugs_in_contact = 1.5\n", 2,
     "[track] lugs_in_contact must be an integer >= 2, got 1.5"),
    ("[track]\nload_bearing_length_mm = 0\n", 2, "[track] load_bearing_length_mm must be a number > 0"),
    ("[track]\n\nlug_pitch_mm = \"18\"\n", 3, "[track] lug_pitch_mm must be a number > 0, got '18'"),
    ("[vehicle]\nmass_kg = -2.0\n", 2, "[vehicle] mass_kg must be a number > 0, got -2.0"),
    ("[camera]\nfps = nan\n", 2, "[camera] fps must be a number > 0"),
    ("[markers]\nbody = \"C1\"\n", 2, "[markers] body must be a list of marker names"),
    ("[markers]\nbody = [\"C1\"]\nlug = [\"C1\"]\n", 3, "marker C1 is listed both as body and as lug"),
    ("[track]\nload_bearing_length_mm = 1e300\n", 2, "[track] load_bearing_length_mm = 1e+300 mm "
     "is outside the plausible range 1 to 100000 mm"),
    ("[track]\nload_bearing_length_mm = inf\n", 2, "load_bearing_length_mm must be a number > 0"),
    ("[track]\nload_bearing_length_mm = -127\n", 2, "load_bearing_length_mm must be a number > 0"),
    ("[track]\nload_bearing_length_mm = 0.001\n", 2, "outside the plausible range 1 to 100000 mm"),
    ("[track]\nlugs_in_contact = 1\n", 2, "lugs_in_contact must be an integer >= 2, got 1"),
    ("[track]\nlugs_in_contact = 1e6\n", 2, "outside the plausible range 2 to 1000 lugs"),
    ("[track]\nlugs_in_contact = %d\n" % 10 ** 400, 2, "outside the plausible range 2 to 1000"),
    ("[track]\nlug_pitch_mm = %d\n" % 10 ** 400, 2, "lug_pitch_mm = 1000000"),
    ("[track]\nlug_pitch_mm = 1e-9\n", 2, "lug_pitch_mm = 1e-09 mm is outside the plausible"),
    ("[vehicle]\nmass_kg = 1e12\n", 2, "mass_kg = 1e+12 kg is outside the plausible range"),
    ("[camera]\nfps = -inf\n", 2, "[camera] fps must be a number > 0"),
    ("[camera]\nfps = 1e12\n", 2, "[camera] fps = 1e+12 frames/s is outside the plausible"),
    ("track = 3\n", 1, "[track] must be a table"),
    ("[track]\nlugs_in_contact 8\n", 2, "invalid TOML"),
]


@pytest.mark.parametrize("text,line,problem", RIG_BAD, ids=[b[2][:40] for b in RIG_BAD])
def test_rig_validation(tmp_path, text, line, problem):
    path = _write(tmp_path, text, "rig.toml")
    with pytest.raises(InputError) as err:
        read_rig(path)
    assert str(err.value).startswith(f"{path}:{line}: ")
    assert problem in str(err.value)


def test_rig_validates_when_built_in_code():
    with pytest.raises(InputError, match=r"\[vehicle\] mass_kg must be a number > 0"):
        Rig(mass_kg=0)
    with pytest.raises(InputError, match="lugs_in_contact"):
        Rig(lugs_in_contact=True)
    assert Rig(body_markers=["C1"]).body_markers == ("C1",)


def test_find_rig(tmp_path):
    csv_path = str(tmp_path / "run7.csv")
    assert find_rig(csv_path) == Rig.reference()
    write_rig(tmp_path / "rig.toml", Rig(mass_kg=3.0))
    assert find_rig(csv_path).mass_kg == 3.0
    write_rig(tmp_path / "run7.rig.toml", Rig(mass_kg=4.0))
    assert find_rig(csv_path).mass_kg == 4.0  # the file's own rig wins
    assert find_rig(str(tmp_path / "other.csv")).mass_kg == 3.0


# -- JSON -----------------------------------------------------------------------------------

def test_json_numpy_and_non_finite(tmp_path):
    path = tmp_path / "fit.json"
    obj = {"slip": {"value": np.float64(0.125), "std": np.float32(0.5), "ci95": np.array([0.1, 0.2])},
           "n": np.int64(7), "ok": np.bool_(True), "bad": float("nan"),
           "arr": np.array([[1.0, np.inf], [np.nan, -2.0]]), "t": (1, 2), 3: "key"}
    write_json(path, obj)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert text.startswith('{\n  "slip": {\n    "value": 0.125')
    back = read_json(path)
    assert back == {"slip": {"value": 0.125, "std": 0.5, "ci95": [0.1, 0.2]}, "n": 7, "ok": True,
                    "bad": None, "arr": [[1.0, None], [None, -2.0]], "t": [1, 2], "3": "key"}
    assert json.loads(text) == back


def test_json_failures(tmp_path):
    path = tmp_path / "fit.json"
    path.write_text("{}\n")
    with pytest.raises(TypeError, match=r"slip\.value"):
        write_json(path, {"slip": {"value": object()}})
    assert path.read_text() == "{}\n" and os.listdir(tmp_path) == ["fit.json"]
    path.write_text('{\n  "a": 1,\n  "b": \n}\n')
    with pytest.raises(InputError, match=r"fit\.json:4: column 1: invalid JSON: Expecting value"):
        read_json(path)
    path.write_text('{"a": NaN}')
    with pytest.raises(InputError, match="NaN"):
        read_json(path)


def test_import_is_light():
    code = ("import sys, fitlug.io; "
            "print([m for m in ('jax', 'cv2', 'matplotlib') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_large_file_reads_correctly(tmp_path):
    # 10^5 rows: the vectorised path must give the same numbers as the values written
    n_frames, markers = 20_000, ("C1", "C2", "B1", "B2", "B3")
    rng = np.random.default_rng(5)
    m = len(markers)
    rec = Recording(markers=markers, roles=("body", "body", "lug", "lug", "lug"),
                    t=np.tile(np.arange(n_frames) * 1e-3, m),
                    marker_index=np.repeat(np.arange(m), n_frames),
                    x=rng.normal(0, 100, m * n_frames), y=rng.normal(0, 100, m * n_frames))
    path = tmp_path / "big.csv"
    write_trajectories(path, rec)
    assert path.read_text().count("\n") == m * n_frames + 1
    back = read_trajectories(path)
    assert back == rec
    assert math.isclose(back.fps, 1000.0, rel_tol=1e-9)


# -- issue 11: the reference recording, broken one way at a time ----------------------------

REF_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                       "reference")
REF_CSV = os.path.join(REF_DIR, "trajectories.csv")


def _ref_lines():
    with open(REF_CSV, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    n_meta = sum(1 for line in lines if line.startswith("#"))
    return lines[:n_meta], lines[n_meta], lines[n_meta + 1:]


@pytest.mark.parametrize("stamp", ["649.0", "1e5", "-1e5", "1e300"])
def test_a_time_stamp_far_off_is_named_by_its_line(tmp_path, stamp):
    meta, header, rows = _ref_lines()
    fields = rows[-1].split(",")
    fields[0] = stamp
    rows[-1] = ",".join(fields)
    path = _write(tmp_path, "\n".join(meta + [header] + rows) + "\n")
    with pytest.raises(InputError) as err:
        read_trajectories(path)
    last = len(meta) + 1 + len(rows)  # the physical line of the last row
    assert str(err.value).startswith(f"{path}:{last}: time_s = {float(stamp)!r} breaks the "
                                     "frame rate")
    assert "frame intervals of 0.01 s" in str(err.value)


def test_rows_fully_shuffled_read_like_the_sorted_file(tmp_path):
    meta, header, rows = _ref_lines()
    shuffled = list(rows)
    np.random.default_rng(11).shuffle(shuffled)
    a = read_trajectories(REF_CSV)
    b = read_trajectories(_write(tmp_path, "\n".join(meta + [header] + shuffled) + "\n"))
    assert set(a.markers) == set(b.markers)
    for name in a.markers:
        sa, sb = a.marker_index == a.markers.index(name), b.marker_index == b.markers.index(name)
        for field in ("t", "x", "y", "frame"):
            assert np.array_equal(getattr(a, field)[sa], getattr(b, field)[sb]), (name, field)
        assert a.role_of(name) == b.role_of(name)


def test_a_repeated_identical_row_is_dropped_with_a_warning(tmp_path):
    meta, header, rows = _ref_lines()
    path = _write(tmp_path, "\n".join(meta + [header] + rows + [rows[7]]) + "\n")
    with pytest.warns(UserWarning, match=r"1 repeated row\(s\)"):
        rec = read_trajectories(path)
    assert rec == read_trajectories(REF_CSV).with_(path=path)


@pytest.mark.parametrize("fps,where", [("50", "meta"), ("103", "meta"), ("200", "rig"),
                                       ("99.9", None), ("100", None)])
def test_fps_that_disagrees_with_the_time_stamps(tmp_path, fps, where):
    meta, header, rows = _ref_lines()  # 100 fps, frame numbers step by one
    rig = None
    if where == "meta":
        meta = [f"# fps: {fps}"] + [m for m in meta if not m.startswith("# fps")]
    elif where == "rig":
        rig_path = tmp_path / "rig.toml"
        rig_path.write_text(f"[camera]\nfps = {fps}\n")
        rig = read_rig(rig_path)
    else:
        rig = Rig(fps=float(fps))
    path = _write(tmp_path, "\n".join(meta + [header] + rows) + "\n")
    if where is None:  # within 2 %
        assert read_trajectories(path, rig=rig).n_samples == len(rows)
        return
    with pytest.raises(InputError) as err:
        read_trajectories(path, rig=rig)
    message = str(err.value)
    if where == "meta":
        assert message.startswith(f"{path}:1: metadata fps {fps} disagrees")
    else:
        assert message.startswith(f"{rig_path}: [camera] fps {fps} disagrees")
    assert "= 100 fps" in message


def test_fps_of_a_decimated_recording_agrees_through_its_frame_numbers(tmp_path):
    meta, header, rows = _ref_lines()
    every_other = [r for r in rows if int(r.split(",")[5]) % 2 == 0]  # frames 0, 2, 4, ...
    path = _write(tmp_path, "\n".join(meta + [header] + every_other) + "\n")
    assert read_trajectories(path).fps == 100.0  # '# fps: 100' with frames stepping by 2
    no_frames = "\n".join(meta + [header.rsplit(",", 1)[0]]
                          + [r.rsplit(",", 1)[0] for r in every_other]) + "\n"
    with pytest.raises(InputError, match="metadata fps 100 disagrees .* = 50 fps"):
        read_trajectories(_write(tmp_path, no_frames, "noframes.csv"))


# -- plausibility before the fit (fitlug.fit._checks), on the reference recording ------------

def _ref_variant(name, **changes):
    return read_trajectories(REF_CSV).with_(path=name, **changes)


def test_build_problem_refuses_positions_in_metres():
    from fitlug.fit._problem import build_problem
    ref = read_trajectories(REF_CSV)
    with pytest.raises(InputError, match=r"^metres\.csv: the markers' vertical spread in a "
                                         r"frame is 0\.07\d+ mm .* look like metres"):
        build_problem(ref.with_(path="metres.csv", x=ref.x / 1000, y=ref.y / 1000),
                      read_rig(os.path.join(REF_DIR, "rig.toml")))


def test_plausibility_checks_name_what_looks_wrong():
    from fitlug.fit._checks import check_recording
    ref = read_trajectories(REF_CSV)
    rig = read_rig(os.path.join(REF_DIR, "rig.toml"))
    assert check_recording(ref, rig) is ref
    with pytest.raises(InputError, match=r"7\.\d+e\+04 mm .* look like micrometres"):
        check_recording(ref.with_(x=ref.x * 1000, y=ref.y * 1000), rig)
    with pytest.raises(InputError, match="time stamps look like milliseconds"):
        check_recording(ref.with_(t=ref.t * 1000), Rig())
    noisy = np.random.default_rng(1).normal(0, 3.0, ref.x.shape)  # 3 mm of noise
    with pytest.raises(InputError, match=r"position noise .* is [23](\.\d+)? mm, above "
                                         r"the plausible 1 mm: the tracker failed"):
        check_recording(ref.with_(x=ref.x + noisy, y=ref.y + noisy), rig)
    fast = ref.with_(t=ref.t / 100)  # 108 mm/s -> 10.8 m/s
    with pytest.raises(InputError, match="10.8 m/s, above the plausible 10 m/s"):
        check_recording(fast, Rig(fps=10000.0))
    with pytest.raises(InputError, match=r"\[camera\] fps 50 disagrees"):
        check_recording(ref, Rig(fps=50.0))
    far = ref.t.copy()
    far[np.argmax(far)] = 649.0
    with pytest.raises(InputError, match=r"time_s = 649\.0 breaks the frame rate: a gap of "
                                         r"642\.51 s against a frame interval of 0\.01 s"):
        check_recording(ref.with_(t=far), rig)


def test_a_robot_that_never_moves_is_named():
    from fitlug.fit._checks import check_recording
    ref = read_trajectories(REF_CSV)
    starts = np.searchsorted(ref.marker_index, np.arange(ref.n_markers))  # sorted by marker
    rng = np.random.default_rng(2)
    x0, y0 = ref.x[starts][ref.marker_index], ref.y[starts][ref.marker_index]
    still = ref.with_(x=x0 + rng.normal(0, 0.005, x0.shape), y=y0 + rng.normal(0, 0.005, x0.shape))
    with pytest.raises(InputError, match=r"the robot never moves: its body markers travel "
                                         r"0\.0\d+ mm in 6\.49 s"):
        check_recording(still, Rig())
    body = np.isin(ref.marker_index, ref.markers_of("body"))
    stuck = ref.with_(x=np.where(body, still.x, ref.x), y=np.where(body, still.y, ref.y))
    with pytest.raises(InputError, match="the track turns but the body stands still"):
        check_recording(stuck, Rig())


def test_an_empty_marker_is_dropped_by_name():
    from fitlug.fit._checks import check_recording
    ref = read_trajectories(REF_CSV)
    gone = ref.marker_index == ref.markers.index("B05")
    rec = ref.with_(x=np.where(gone, np.nan, ref.x), y=np.where(gone, np.nan, ref.y))
    with pytest.warns(UserWarning, match=r"marker\(s\) B05 have no valid sample"):
        kept = check_recording(rec, Rig())
    assert "B05" not in kept.markers and kept.n_markers == ref.n_markers - 1
    assert kept.n_samples == ref.n_samples - int(gone.sum())
    for name in kept.markers:  # every other marker untouched
        a = ref.marker_index == ref.markers.index(name)
        b = kept.marker_index == kept.markers.index(name)
        assert np.array_equal(ref.x[a], kept.x[b]) and np.array_equal(ref.t[a], kept.t[b])
    body = np.isin(ref.marker_index, ref.markers_of("body"))
    with pytest.raises(InputError, match=r"every body marker \(C1, C2\) is empty"):
        check_recording(ref.with_(x=np.where(body, np.nan, ref.x)), Rig())


def test_wide_rows_in_any_order(tmp_path):
    text = "time_s,frame,C1_x_mm,C1_y_mm,B1_x_mm,B1_y_mm\n" \
           "0.02,2,5,6,7,8\n0.00,0,1,2,3,4\n0.01,1,,,5,6\n0.00,0,1,2,3,4\n"
    with pytest.warns(UserWarning, match="repeated row"):
        rec = read_trajectories(_write(tmp_path, text))
    assert rec.markers == ("C1", "B1") and rec.roles == ("body", "lug")
    assert rec.t.tolist() == [0.0, 0.01, 0.02] * 2 and rec.frame.tolist() == [0, 1, 2] * 2
    assert np.array_equal(rec.x, [1, np.nan, 5, 3, 5, 7], equal_nan=True)
    assert rec.y.tolist()[3:] == [4.0, 6.0, 8.0]
    backwards = text.replace("0.02,2,", "0.005,2,").rsplit("0.00,0", 1)[0]
    with pytest.raises(InputError, match=r":4: time going backwards for every marker: frame 1 "
                                         r"at 0\.01 s here, frame 2 at 0\.005 s on line 2"):
        read_trajectories(_write(tmp_path, backwards, "b.csv"))


def test_stage_functions_stay_callable_once_their_packages_are_imported():
    """`fitlug.fit(rec, rig)` (the README's call) failed with "'module' object is not
    callable" once anything had imported the sub-package fitlug.fit (fitlug.explain does):
    the import system binds the name to the module."""
    import importlib

    import fitlug

    for name in ("fit", "explain", "campaign"):
        mod = importlib.import_module(f"fitlug.{name}")
        assert callable(getattr(fitlug, name)), name
        assert callable(mod), name
    with pytest.raises(Exception) as direct:
        fitlug.fit.fit(None)
    with pytest.raises(type(direct.value)):
        fitlug.fit(None)

"""Issue 30, item 5: every input or option that used to give a traceback, a hang or a
misleading line gives a clean one-line error (naming the file or option, the place and the
problem), quickly. Each case here is small: the bundled reference recording changed as a
user or tracker would change it, synthetic files, or argument parsing only."""

import os

import pytest

from fitlug.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REF = os.path.join(ROOT, "data", "reference", "trajectories.csv")


def _one_error_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0] and "Warning" not in err[0], err
    return err[0]


def _refused_at_parsing(argv, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if "error:" in ln]
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("argv,words", [
    (["--seed", "-1"], ("--seed", "-1", "0 .. 4294967295")),
    (["--seed", "99999999999999999999999"], ("--seed", "out of range")),
    (["--seed", "1.5"], ("--seed", "not an integer")),
    (["--mcmc-budget", "0"], ("--mcmc-budget", "> 0")),
    (["--mcmc-budget", "nan"], ("--mcmc-budget", "finite")),
    (["--mcmc-budget=-inf"], ("--mcmc-budget", "finite")),
    (["--mcmc-budget", "abc"], ("--mcmc-budget", "not a number")),
])
def test_bad_seed_and_budget_refused_before_any_fit(argv, words, capsys, tmp_path):
    out = tmp_path / "fit"
    line = _refused_at_parsing([REF, "--out", str(out)] + argv, capsys)
    for w in words:
        assert w in line, line
    assert not out.exists()  # refused before any work


def test_campaign_and_simulate_refuse_bad_seed(capsys):
    assert "--seed" in _refused_at_parsing(["campaign", REF, "--seed", "-1"], capsys)
    assert "--mcmc-budget" in _refused_at_parsing(["campaign", REF, "--mcmc-budget", "0"], capsys)
    assert "--seed" in _refused_at_parsing(["simulate", "--seed", "2e40"], capsys)


def test_largest_seed_accepted():
    from fitlug.cli._common import SEED_MAX, seed_arg

    assert seed_arg(str(SEED_MAX)) == SEED_MAX == 2 ** 32 - 1
    import numpy as np

    np.random.default_rng(SEED_MAX)  # the range documented is one numpy takes
    np.random.RandomState(SEED_MAX)  # and emcee's legacy generator


def _state_bytes() -> bytes:
    import io
    import json

    import numpy as np

    buf = io.BytesIO()
    rng = np.random.default_rng(1)
    np.savez_compressed(buf, meta=np.array(json.dumps({"run_id": "x"})),
                        t=rng.normal(size=20000), y=rng.normal(size=20000))
    return buf.getvalue()


@pytest.mark.parametrize("damage", ["truncated", "cut_short", "bit_flips", "empty", "text"])
def test_report_on_a_damaged_state_file_is_one_line(damage, tmp_path, capsys):
    good = _state_bytes()
    data = {"truncated": good[: len(good) // 2], "cut_short": good[:-30], "empty": b"",
            "text": b"not a zip file\n"}.get(damage)
    if damage == "bit_flips":
        b = bytearray(good)
        for i in range(200, len(b) - 200, 997):
            b[i] ^= 0xFF
        data = bytes(b)
    (tmp_path / "fit.json").write_text('{"run_id": "x"}')
    (tmp_path / "state.npz").write_bytes(data)
    assert main(["report", str(tmp_path)]) == 2
    line = _one_error_line(capsys)
    assert "state.npz" in line and "truncated or damaged" in line, line
    assert not (tmp_path / "report.html").exists()


def _reference_rows():
    with open(REF) as fh:
        lines = fh.read().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    rows = [ln for ln in lines if not ln.startswith("#")]
    return head, rows[0], rows[1:]


def _write(path, head, columns, rows):
    path.write_text("\n".join(head + [columns] + rows) + "\n")
    return str(path)


def test_a_new_marker_id_every_frame_is_refused_as_unlinked(tmp_path, capsys):
    head, columns, rows = _reference_rows()
    new = []
    for r in rows:  # B01 at frame 7 becomes B01_7: 7800 ids in 650 frames
        f = r.split(",")
        f[1] = f"{f[1]}_{f[5]}"
        new.append(",".join(f))
    path = _write(tmp_path / "trajectories.csv", head, columns, new)
    assert main([path, "--no-mcmc", "--no-explain", "--no-report",
                 "--out", str(tmp_path / "fit")]) == 2
    line = _one_error_line(capsys)
    assert "trajectories.csv" in line and "7800 marker ids in 650 frames" in line, line
    assert "link the tracks first" in line and "never moves" not in line, line


def test_many_distinct_ids_are_judged_in_linear_time(tmp_path):
    """2*10^5 ids, one sample each: refused in well under a second by the library (the
    per-marker loops were markers x samples: a hang at 10^6)."""
    import time

    import numpy as np

    from fitlug.fit._checks import _per_marker, check_marker_ids
    from fitlug.io import read_trajectories

    n = 200_000
    t = np.arange(n) / 1000.0
    body = np.arange(n) % 2 == 1
    lines = ["time_s,marker,role,x_mm,y_mm"] + [
        f"{t[i]:.3f},M{i},{'body' if body[i] else 'lug'},{10 * t[i]:.4f},{40 * body[i]}"
        for i in range(n)]
    (tmp_path / "ids.csv").write_text("\n".join(lines) + "\n")
    rec = read_trajectories(tmp_path / "ids.csv")
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="a new marker id on nearly every frame"):
        check_marker_ids(rec)
    per = _per_marker(rec, "body")
    assert time.perf_counter() - t0 < 5.0
    assert len(per) == n // 2 and all(p[0].size == 1 for p in per[:100])


def test_per_marker_keeps_each_markers_samples_in_order():
    import numpy as np

    from fitlug.fit._checks import _per_marker
    from fitlug.io import read_trajectories

    rec = read_trajectories(REF)
    for role in ("body", "lug"):
        got = _per_marker(rec, role)
        ids = [m for m, r in enumerate(rec.roles) if r == role]
        assert len(got) == len(ids)
        for m, (t, x, y) in zip(ids, got):  # the masks the linear version replaced
            sel = rec.valid & (rec.marker_index == m)
            assert np.array_equal(t, rec.t[sel]) and np.array_equal(x, rec.x[sel])
            assert np.array_equal(y, rec.y[sel])


def _changed_reference(tmp_path, change, name="trajectories.csv"):
    """The reference recording with change(fields) applied to each data row (a list of
    strings: time_s, marker, role, x_mm, y_mm, frame)."""
    head, columns, rows = _reference_rows()
    new = []
    for i, r in enumerate(rows):
        f = r.split(",")
        change(i, f)
        new.append(",".join(f))
    return _write(tmp_path / name, head, columns, new)


@pytest.mark.parametrize("value", ["1e300", "-1e300", "2e7"])
def test_one_absurd_coordinate_is_one_line_with_its_line(value, tmp_path, capsys):
    def change(i, f):
        if i == 3000:
            f[3] = value
    path = _changed_reference(tmp_path, change)
    with __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("error")  # no numpy warning on the way
        assert main([path, "--no-mcmc", "--no-explain", "--no-report",
                     "--out", str(tmp_path / "fit")]) == 2
    line = _one_error_line(capsys)
    # the header is 4 lines (3 comments + columns): data row 3000 is line 3005
    assert "trajectories.csv:3005" in line and "x_mm" in line and value in line, line


def test_absurd_coordinate_in_memory_is_refused_by_the_fit():
    import numpy as np

    from fitlug.fit import fit
    from fitlug.io import read_trajectories

    rec = read_trajectories(REF)
    y = rec.y.copy()
    y[123] = np.inf
    with pytest.raises(ValueError, match=r"absurd y_mm inf of marker \w+ at time_s"):
        fit(rec.with_(y=y), None)


def test_time_jitter_is_named_not_a_missing_sigma_column(tmp_path, capsys):
    import numpy as np

    rng = np.random.default_rng(3)
    jitter = rng.uniform(-0.002, 0.002, size=1000)  # +-2 ms per frame, at 100 fps

    def change(i, f):
        f[0] = f"{float(f[0]) + jitter[int(f[5])]:.6f}"
    path = _changed_reference(tmp_path, change)
    assert main([path, "--no-mcmc", "--no-explain", "--no-report",
                 "--out", str(tmp_path / "fit")]) == 2
    line = _one_error_line(capsys)
    assert "time stamps are irregular" in line and "ms apart around" in line, line
    lo, hi = (float(v) for v in line.split("frames are ")[1].split(" ms apart")[0].split(" to "))
    assert 6.0 <= lo < 8.0 and 12.0 < hi <= 14.0, line  # steps of 10 +- 4 ms


def test_irregular_time_stamps_phrase():
    import numpy as np

    from fitlug.fit._noise import irregular_time_stamps

    t = np.arange(500) / 100.0
    assert irregular_time_stamps(t) is None
    assert irregular_time_stamps(np.r_[t[:100], t[150:]]) is None  # a gap is no jitter
    assert irregular_time_stamps(t + np.random.default_rng(0).uniform(-2e-3, 2e-3, 500))


@pytest.mark.parametrize("extra,where,words", [
    ("Total rows: 7800", "end", ("not a data row", "'Total rows: 7800'", "after the data")),
    ("camera restarted here", 100, ("not a data row", "among the data")),
])
def test_a_line_that_is_not_data_is_named_as_such(extra, where, words, tmp_path, capsys):
    from fitlug.io import read_trajectories

    head, columns, rows = _reference_rows()
    at = len(rows) if where == "end" else where
    path = _write(tmp_path / "t.csv", head, columns, rows[:at] + [extra] + rows[at:])
    with pytest.raises(ValueError) as e:
        read_trajectories(path)
    msg = str(e.value)
    assert f"t.csv:{len(head) + 2 + at}:" in msg, msg
    for w in words:
        assert w in msg, msg
    assert "separator" not in msg


def test_a_row_with_another_separator_still_says_separator(tmp_path):
    from fitlug.io import read_trajectories

    head, columns, rows = _reference_rows()
    rows[10] = rows[10].replace(",", ";")
    path = _write(tmp_path / "t.csv", head, columns, rows)
    with pytest.raises(ValueError, match=r"t.csv:15: the separator looks wrong: ';'"):
        read_trajectories(path)


def test_rig_toml_with_a_bom_is_read(tmp_path):
    from fitlug.io import read_rig

    src = os.path.join(ROOT, "data", "reference", "rig.toml")
    with open(src, "rb") as fh:
        raw = fh.read()
    (tmp_path / "rig.toml").write_bytes(b"\xef\xbb\xbf" + raw)  # as Notepad saves it
    assert read_rig(tmp_path / "rig.toml") == read_rig(src)


def test_json_with_a_bom_is_read(tmp_path):
    from fitlug.io import read_json

    (tmp_path / "a.json").write_bytes(b"\xef\xbb\xbf" + b'{"a": 1}')
    assert read_json(tmp_path / "a.json") == {"a": 1}


def test_gzip_trajectories_are_read_transparently(tmp_path):
    import gzip

    import numpy as np

    from fitlug.io import read_any, read_trajectories

    with open(REF, "rb") as fh:
        raw = fh.read()
    (tmp_path / "t.csv.gz").write_bytes(gzip.compress(raw))
    a, b = read_trajectories(REF), read_any(tmp_path / "t.csv.gz")
    assert a.markers == b.markers and np.array_equal(a.x, b.x, equal_nan=True)


@pytest.mark.parametrize("kind", ["cut", "twice"])
def test_damaged_or_double_gzip_is_named(kind, tmp_path):
    import gzip

    from fitlug.io import read_any

    with open(REF, "rb") as fh:
        z = gzip.compress(fh.read())
    data = z[:20000] if kind == "cut" else gzip.compress(z)
    (tmp_path / "t.csv").write_bytes(data)
    with pytest.raises(ValueError) as e:
        read_any(tmp_path / "t.csv")
    msg = str(e.value)
    assert "t.csv" in msg and "gzip-compressed" in msg and "UTF-8" not in msg, msg
    assert ("truncated or damaged" if kind == "cut" else "compressed twice") in msg


def test_campaign_exits_non_zero_naming_the_failed_recordings(monkeypatch, tmp_path, capsys):
    """The CLI's exit status from a campaign result with a failure (the campaign itself
    records failures: tests/test_campaign.py test_failing_recording_does_not_stop_campaign
    runs the whole path)."""
    from types import SimpleNamespace

    import fitlug.campaign

    ok = SimpleNamespace(name="a_0N", status="fitted", error=None)
    bad = SimpleNamespace(name="zz_bad", status="failed",
                          error="zz_bad/trajectories.csv:2: text in number column x_mm: 'x'")
    res = SimpleNamespace(recordings=[ok, bad], law="linear", delta_bic=1.0,
                          stiffness={"value": 0.25, "std": 0.01, "ci95": [0.23, 0.27]},
                          rolling_resistance={}, F_max=None, flagged=[], failed=[bad])
    monkeypatch.setattr(fitlug.campaign, "campaign", lambda *a, **k: res)
    assert main(["campaign", "x", "--out", str(tmp_path), "--workers", "0", "-q"]) == 1
    line = _one_error_line(capsys)
    assert "1 of 2 recording(s) failed (zz_bad)" in line and "campaign.json" in line, line
    res.recordings, res.failed = [ok], []
    assert main(["campaign", "x", "--out", str(tmp_path), "--workers", "0", "-q"]) == 0


def test_noise_with_too_few_frames_says_so(tmp_path, capsys):
    line = _refused_at_parsing(["noise", str(tmp_path), "--frames", "2"], capsys)
    assert "--frames" in line and "too few frames" in line and "at least 10" in line, line
    import numpy as np
    from PIL import Image

    for i in range(4):  # a folder of 4 frames: refused before the tracker runs
        Image.fromarray(np.zeros((40, 60), np.uint8)).save(tmp_path / f"f{i:03d}.png")
    assert main(["noise", str(tmp_path)]) == 2
    line = _one_error_line(capsys)
    assert str(tmp_path) in line and "too few frames: 4" in line and "no marker" not in line


def test_calibrate_without_a_board_reports_each_image_and_stops_early(tmp_path, capsys):
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(0)
    for i in range(14):  # textured frames with no board in them
        Image.fromarray(rng.integers(0, 255, (120, 160), dtype=np.uint8)).save(
            tmp_path / f"f{i:02d}.png")
    assert main(["calibrate", str(tmp_path), "--board", "chessboard:9x6", "--square", "10",
                 "-o", str(tmp_path / "calib.json")]) == 2
    cap = capsys.readouterr()
    progress = [ln for ln in cap.out.splitlines() if ln.startswith("[calibrate] ")]
    assert len(progress) == 1 + 10, progress  # the start, then one line per image searched
    assert progress[-1].startswith("[calibrate] 10/14 f09.png: no 9x6 chessboard found")
    err = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert len(err) == 1 and "no board" in err[0] and "first 10 of 14 images" in err[0], err
    assert str(tmp_path) in err[0] and not (tmp_path / "calib.json").exists()


@pytest.mark.parametrize("ending", ["\r\n", "\r"])
def test_line_endings_read_as_before(ending, tmp_path):
    """The reader splits the text line by line itself now (no io.StringIO copy): CRLF and
    old-Mac CR files still read as the LF original."""
    import numpy as np

    from fitlug.io import read_trajectories

    with open(REF, newline="") as fh:
        text = fh.read()
    (tmp_path / "t.csv").write_bytes(text.replace("\n", ending).encode())
    a, b = read_trajectories(REF), read_trajectories(tmp_path / "t.csv")
    assert a.markers == b.markers and np.array_equal(a.t, b.t)
    assert np.array_equal(a.x, b.x, equal_nan=True) and np.array_equal(a.y, b.y, equal_nan=True)

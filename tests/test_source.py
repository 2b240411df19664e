"""open_source on synthetic videos and frame folders whose content is known exactly."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from fitlug._errors import InputError
from fitlug.vision.read._source import open_source

cv2 = pytest.importorskip("cv2")


def _frames(n, shape=(48, 64), dtype=np.uint8, seed=0):
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 65535
    return [rng.integers(0, top + 1, shape, dtype=dtype) for _ in range(n)]


def _write_video(path, frames, fps, fourcc="FFV1", colour=False):
    h, w = frames[0].shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h), colour)
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if colour else f)
    writer.release()


def test_lossless_video_round_trip(tmp_path):
    frames = _frames(12)
    path = tmp_path / "clip.avi"
    _write_video(path, frames, 25)
    with open_source(path) as src:
        assert len(src) == 12 and src.fps == 25 and src.shape == (48, 64) and src.bit_depth == 8
        np.testing.assert_allclose(src.times(), np.arange(12) / 25)
        got = list(src)
        assert [i for i, _, _ in got] == list(range(12))
        for (i, t, f), truth in zip(got, frames):
            assert f.dtype == np.float32 and t == pytest.approx(i / 25)
            np.testing.assert_array_equal(f, truth)
        # random access, backwards and forwards
        np.testing.assert_array_equal(src.frame(7), frames[7])
        np.testing.assert_array_equal(src.frame(2), frames[2])
        np.testing.assert_array_equal(src.frame(-1), frames[-1])
        with pytest.raises(IndexError):
            src.frame(12)


def test_colour_video_to_grey(tmp_path):
    # a uniform colour frame: grey = 0.299 R + 0.587 G + 0.114 B (ITU-R BT.601)
    bgr = np.zeros((32, 32, 3), np.uint8)
    bgr[:] = (200, 100, 50)  # B, G, R
    path = tmp_path / "colour.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (32, 32), True)
    for _ in range(3):
        writer.write(bgr)
    writer.release()
    with open_source(path) as src:
        grey = src.frame(1)
    assert grey.shape == (32, 32)
    assert np.abs(grey - (0.299 * 50 + 0.587 * 100 + 0.114 * 200)).max() <= 2.0  # YUV round trip


def test_selection_on_video(tmp_path):
    frames = _frames(20, seed=1)
    path = tmp_path / "clip.mkv"
    _write_video(path, frames, 50)
    with open_source(path, frames=slice(3, 17, 4)) as src:
        assert len(src) == 4
        np.testing.assert_array_equal(src.indices, [3, 7, 11, 15])
        np.testing.assert_allclose(src.times(), np.array([3, 7, 11, 15]) / 50)
        for i, t, f in src:
            np.testing.assert_array_equal(f, frames[i])
    with open_source(path, frames=[19, 0, 5], fps=1000) as src:
        assert src.fps == 1000
        assert [i for i, _, _ in src] == [19, 0, 5]
        for i, _, f in src:
            np.testing.assert_array_equal(f, frames[i])
    with pytest.raises(InputError, match="empty"):
        open_source(path, frames=(30, 40))


def test_video_iteration_streams(tmp_path):
    frames = _frames(60, shape=(120, 160), seed=2)
    path = tmp_path / "long.avi"
    _write_video(path, frames, 30)
    with open_source(path) as src:
        tracemalloc.start()
        n = sum(1 for _ in src)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert n == 60
    one = 120 * 160 * 4
    assert peak < 8 * one  # all 60 frames would be 60 * one


def test_folder_of_16bit_png_natural_order(tmp_path):
    frames = _frames(11, shape=(20, 30), dtype=np.uint16, seed=3)
    for k, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"img{k + 1}.png"), f)  # img1 .. img11, not zero-padded
    (tmp_path / "notes.txt").write_text("not a frame")
    with pytest.raises(InputError, match="fps"):
        open_source(tmp_path)
    with open_source(tmp_path, fps=500) as src:
        assert len(src) == 11 and src.bit_depth == 16 and src.shape == (20, 30)
        for i, t, f in src:
            assert t == pytest.approx(i / 500)
            np.testing.assert_array_equal(f, frames[i])  # 16-bit levels kept


def test_tiff_list_and_mismatched_frame(tmp_path):
    frames = _frames(3, shape=(10, 12), seed=4)
    files = []
    for k, f in enumerate(frames):
        files.append(str(tmp_path / f"f{k}.tif"))
        cv2.imwrite(files[-1], f)
    with open_source(files[::-1], fps=10) as src:
        np.testing.assert_array_equal(src.frame(0), frames[2])
    cv2.imwrite(files[1], np.zeros((11, 12), np.uint8))
    with open_source(files, fps=10) as src:
        with pytest.raises(InputError, match=r"f1\.tif.*unlike the first"):
            list(src)


def test_bad_sources(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        open_source(tmp_path / "missing.avi")
    empty = tmp_path / "empty.avi"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        open_source(empty)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(5).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match=r"junk\.mp4"):
        open_source(junk)
    folder = tmp_path / "nothing"
    folder.mkdir()
    with pytest.raises(InputError, match="no image files"):
        open_source(folder, fps=10)
    bad_png = tmp_path / "frames"
    bad_png.mkdir()
    (bad_png / "a.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(InputError, match=r"a\.png.*corrupt"):
        open_source(bad_png, fps=10)
    single = tmp_path / "one.png"
    cv2.imwrite(str(single), np.zeros((4, 4), np.uint8))
    with pytest.raises(InputError, match="single image"):
        open_source(single)
    with pytest.raises(InputError, match="positive"):
        open_source(tmp_path / "frames", fps=-3)


def test_video_without_frame_count(tmp_path, monkeypatch):
    # some containers store no frame count: the reader counts by decoding
    frames = _frames(7, seed=6)
    path = tmp_path / "clip.mkv"
    _write_video(path, frames, 20)
    real = cv2.VideoCapture

    class NoCount:  # a wrapper: subclassing the C++ class crashes at garbage collection
        def __init__(self, name):
            self._cap = real(name)

        def get(self, prop):
            return 0.0 if prop == cv2.CAP_PROP_FRAME_COUNT else self._cap.get(prop)

        def __getattr__(self, name):
            return getattr(self._cap, name)

    monkeypatch.setattr(cv2, "VideoCapture", NoCount)
    with open_source(path) as src:
        assert len(src) == 7
        got = list(src)
    assert [i for i, _, _ in got] == list(range(7))
    for i, _, f in got:
        np.testing.assert_array_equal(f, frames[i])

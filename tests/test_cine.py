"""The .cine reader against DICe's reference frames and the published facts of pims' files.

Reference relation (found from the data, holds for every DICe file here): DICe stores
frame 0 as float32 in 8-bit units, `ref = frame * 255 / (2**bit_depth - 1)`, with our
frame in grey levels of the file's bit depth, row 0 at the top:
8-bit files -> ref == frame exactly; 16-bit files with 12 real bits -> frame * 255/4095;
10-bit packed files -> the table-expanded 12-bit value * 255/4095.
"""

from __future__ import annotations

import glob
import os
import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fitlug._errors import InputError
from fitlug.vision.read._cine import CineFile, _unpack_10, _unpack_12
from fitlug.vision.read._source import open_source

import shared_data  # noqa: E402 - tests/ is on sys.path (conftest)

CINE = os.path.join(shared_data.REAL, "cine")
REFERENCES = sorted(glob.glob(os.path.join(CINE, "*_0.rawi")))
EIGHT_BIT = {"phantom_v1610", "phantom_v1610_raw", "phantom_v9_raw_16bpp"}

pytestmark = pytest.mark.skipif(not os.path.isdir(CINE), reason="real .cine data not present")


def _read_rawi(path):
    raw = Path(path).read_bytes()
    width, height, bytes_per_value = np.frombuffer(raw[:12], "<u4")
    assert bytes_per_value == 4
    return np.frombuffer(raw[12:], "<f4").reshape(height, width)


def test_reference_files_present():
    assert len(REFERENCES) == 11


@pytest.mark.parametrize("ref_path", REFERENCES, ids=lambda p: os.path.basename(p)[:-7])
def test_frame0_matches_dice_reference(ref_path):
    name = os.path.basename(ref_path)[: -len("_0.rawi")]
    ref = _read_rawi(ref_path)
    with open_source(os.path.join(CINE, name + ".cine")) as src:
        assert src.shape == ref.shape == (128, 256)
        assert len(src) == 6
        assert src.bit_depth == (8 if name in EIGHT_BIT else 12)
        frame = src.frame(0)
    assert frame.dtype == np.float32
    predicted = frame.astype(np.float64) * 255.0 / (2**src.bit_depth - 1)
    # float32 rounding of DICe's values is the only difference
    np.testing.assert_allclose(predicted, ref, rtol=2e-7, atol=1e-6)
    if name in EIGHT_BIT:
        np.testing.assert_array_equal(frame, ref)
    # the flip matters: the reference is not symmetric top/bottom
    assert np.abs(predicted[::-1] - ref).max() > 10


def test_packed_file_is_10_bit_companded():
    with CineFile(os.path.join(CINE, "packed_12bpp.cine")) as cine:
        assert cine.packing == "10bit"
        img = cine.read(0)
    assert img.max() <= 4095 and img.min() >= 2  # table[0] = 2


def test_counts_sizes_and_rates_of_pims_files():
    with open_source(os.path.join(CINE, "cine_legacy.cine")) as src:
        assert len(src) == 97 and src.shape == (128, 128)
        stamps = src.cine.time_stamps_s
        # header rate agrees with the per-image time stamps
        assert src.fps * np.median(np.diff(stamps)) == pytest.approx(1.0, rel=1e-3)
    with open_source(os.path.join(CINE, "cine_781.cine")) as src:
        assert len(src) == 15 and src.shape == (256, 256)
        # recorded at 90 000 fps, saved with decimation 10: the file's frames are 1/9000 s apart
        assert src.cine.acquisition_fps == 90000
        assert src.cine.decimation == 10
        assert src.fps == 9000
        assert np.median(np.diff(src.cine.time_stamps_s)) == pytest.approx(1 / 9000, rel=2e-3)
        np.testing.assert_allclose(src.times(), np.arange(15) / 9000)


@pytest.mark.parametrize("name,fps", [("phantom_v611_raw_16bpp", 2000), ("phantom_v7_raw_16bpp", 80),
                                      ("phantom_v9_raw_16bpp", 300), ("phantom_v1610", 100)])
def test_dice_rates_match_time_stamps(name, fps):
    with CineFile(os.path.join(CINE, name + ".cine")) as cine:
        assert cine.fps == fps
        assert np.median(np.diff(cine.time_stamps_s)) == pytest.approx(1 / fps, rel=1e-3)


def test_colour_file_refused_on_one_line():
    path = os.path.join(CINE, "invalid_color.cine")
    with pytest.raises(InputError) as err:
        open_source(path)
    msg = str(err.value)
    assert msg.startswith(path) and "colour" in msg and "\n" not in msg


def test_not_a_cine_and_truncated(tmp_path):
    bogus = tmp_path / "bogus.cine"
    bogus.write_bytes(b"RIFF" + bytes(200))
    with pytest.raises(InputError, match="not a Phantom"):
        open_source(bogus)
    short = tmp_path / "short.cine"
    data = Path(CINE, "cine_legacy.cine").read_bytes()
    short.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated"):
        open_source(short)
    tiny = tmp_path / "tiny.cine"
    tiny.write_bytes(b"CI")
    with pytest.raises(InputError, match=r"tiny\.cine"):
        open_source(tiny)


def test_fps_override_and_selection():
    with open_source(os.path.join(CINE, "cine_legacy.cine"), fps=1000.0, frames=(10, 40, 10)) as src:
        assert src.fps == 1000.0
        got = [(i, t) for i, t, _ in src]
    assert got == [(10, 0.010), (20, 0.020), (30, 0.030)]


def test_iteration_streams_frame_by_frame(tmp_path):
    path = os.path.join(CINE, "cine_legacy.cine")
    with open_source(path) as src:
        first = src.frame(0)
        tracemalloc.start()
        n = 0
        for i, _, frame in src:
            n += 1
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        np.testing.assert_array_equal(src.frame(0), first)
    assert n == 97
    # 97 frames of 64 KiB as float32 would be 6.4 MB; a streaming reader holds a few
    assert peak < 8 * first.nbytes


def test_unpack_bit_order():
    # MSB first: bytes AB CD EF -> 0xABC, 0xDEF
    np.testing.assert_array_equal(_unpack_12(bytes([0xAB, 0xCD, 0xEF])), [0xABC, 0xDEF])
    codes = [0b1100110011, 0b0000011111, 0b1010101010, 0b0111111110]
    bits = "".join(f"{c:010b}" for c in codes)
    packed = bytes(int(bits[k:k + 8], 2) for k in range(0, 40, 8))
    np.testing.assert_array_equal(_unpack_10(packed), codes)


def test_upper_case_extension(tmp_path):
    dst = tmp_path / "renamed.CINE"
    shutil.copy(os.path.join(CINE, "phantom_v1610.cine"), dst)
    with open_source(dst) as src, CineFile(os.path.join(CINE, "phantom_v1610.cine")) as ref:
        assert src.fps == 100
        np.testing.assert_array_equal(src.frame(5), ref.read(5))

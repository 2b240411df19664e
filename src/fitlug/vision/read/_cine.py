"""Reader for Vision Research Phantom `.cine` files (uncompressed monochrome), frame by frame.

Layout (all little-endian, structures packed):

- CINEFILEHEADER (44 bytes at 0): "CI", header size, Compression (0 = grey/interpolated,
  1 = JPEG, 2 = raw Bayer), ImageCount, and the offsets of the BITMAPINFOHEADER
  (OffImageHeader), of SETUP (OffSetup) and of the table of image offsets (OffImageOffsets).
- BITMAPINFOHEADER (40 bytes): biWidth, biHeight, biBitCount (8 or 16; 24/48 colour),
  biCompression (0 = plain; 256 = packed, 10 bits per pixel, companded; 1024 = packed
  12 bits per pixel) and biSizeImage (bytes per image).
- SETUP: byte offsets used here: FrameRate16 (u16 at 0), Length (u16 at 142),
  FrameRate (u32 at 768), CFA (u32 at 808), RealBPP (u32 at 896).
- Tagged blocks from OffSetup + Length to OffImageOffsets, each `u32 size, u16 type,
  u16 reserved, data`: type 1002 holds one TIME64 per image (u64: high 32 bits whole
  seconds, low 32 bits fraction of a second), 1003 one exposure per image (u32 / 2**32 s).
- The table of ImageCount u64 image offsets; at each, an annotation of `AnnotationSize`
  bytes (u32 first, u32 image size last) and then the pixels.

Plain images are stored bottom row first (a Windows DIB with positive biHeight) and are
flipped here so that row 0 is the top. Packed images are stored top row first (DICe's and
pims' readers agree, and DICe's reference frame confirms it for 10-bit). 10-bit codes are
expanded to linear 12-bit values through the format's table, so their `bit_depth` is 12.

Frame rate: SETUP's FrameRate is the acquisition rate. When PCC saves only every N-th
image ("decimation" at saving) it keeps that rate in the header, but the per-image time
stamps are N acquisition periods apart. `fps` is the rate of the frames in the file:
FrameRate / N, with N the time-stamp spacing in acquisition periods rounded to an integer
(N = 1 without time stamps). `acquisition_fps` keeps the header value.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from ..._errors import InputError
from ._cine_lut import LUT_10_TO_12

_FILE_HEADER = struct.Struct("<2sHHHiIiIIIIQ")
_BITMAP_HEADER = struct.Struct("<IiiHHIIiiII")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_BLOCK = struct.Struct("<IHH")

_SETUP_FRAME_RATE_16 = 0
_SETUP_LENGTH = 142
_SETUP_FRAME_RATE = 768
_SETUP_CFA = 808
_SETUP_REAL_BPP = 896

_BI_RGB, _BI_PACKED, _BI_PACKED_12 = 0, 256, 1024
_TAG_TIME_ONLY, _TAG_EXPOSURE = 1002, 1003
_COMPRESSION_NAMES = {1: "JPEG-compressed", 2: "raw colour (uninterpolated Bayer)"}


class CineFile:
    """An open `.cine` file: header facts, and raw frames read one at a time.

    Attributes: `path`, `width`, `height` (px), `n_frames`, `bit_depth` (bits of the grey
    levels `read` returns), `fps` (frame rate of the file, Hz, None when the header has
    none), `acquisition_fps` (header FrameRate, Hz), `decimation` (fps = acquisition_fps /
    decimation), `first_image_no` (number of the first image relative to the trigger),
    `time_stamps_s` ((n_frames,) absolute seconds or None), `exposure_s` (or None),
    `packing` ("none", "10bit" or "12bit").

    Raises InputError (naming the file) for anything it cannot read: not a cine file,
    truncated, colour or compressed images, unknown packing.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        try:
            self._fh = open(self.path, "rb")
        except OSError as exc:
            raise InputError(self.path, f"cannot open: {exc.strerror or exc}") from None
        try:
            self._read_headers()
        except BaseException:
            self._fh.close()
            raise

    # -- headers --------------------------------------------------------------------------
    def _error(self, problem: str, place: str | None = None) -> InputError:
        return InputError(self.path, problem, place=place)

    def _read_at(self, offset: int, size: int, what: str) -> bytes:
        if offset < 0 or offset + size > self._size:
            raise self._error(f"truncated: {what} lies past the end of the file "
                              f"(needs bytes {offset}..{offset + size}, file has {self._size})")
        self._fh.seek(offset)
        return self._fh.read(size)

    def _read_headers(self) -> None:
        self._size = os.fstat(self._fh.fileno()).st_size
        if self._size < _FILE_HEADER.size:
            raise self._error(f"not a Phantom .cine file: only {self._size} bytes")
        (magic, _hsize, compression, _version, _first_movie, _total, first_no, count,
         off_bitmap, off_setup, off_offsets, _trigger) = _FILE_HEADER.unpack(
            self._read_at(0, _FILE_HEADER.size, "the file header"))
        if magic != b"CI":
            raise self._error("not a Phantom .cine file (no 'CI' signature)")
        if count == 0:
            raise self._error("the .cine file holds no images", place="ImageCount")
        (_bisize, width, height, _planes, bit_count, bi_compression, size_image,
         *_rest) = _BITMAP_HEADER.unpack(self._read_at(off_bitmap, _BITMAP_HEADER.size,
                                                      "the bitmap header"))
        setup_len = _U16.unpack(self._read_at(off_setup + _SETUP_LENGTH, 2, "SETUP"))[0]

        def setup_u32(offset: int) -> int | None:
            if offset + 4 > setup_len:  # old files end SETUP before the newer fields
                return None
            return _U32.unpack(self._read_at(off_setup + offset, 4, "SETUP"))[0]

        cfa = setup_u32(_SETUP_CFA) or 0
        if compression != 0 or cfa != 0 or bit_count in (24, 48):
            kind = _COMPRESSION_NAMES.get(compression, "colour")
            raise self._error(f"{kind} .cine images (Compression={compression}, CFA={cfa}, "
                              f"{bit_count} bits) are not supported: record or save the cine "
                              "as monochrome, or export greyscale TIFF frames")
        if width <= 0 or height == 0:
            raise self._error(f"bad image size {width}x{height}", place="BITMAPINFOHEADER")
        self._bottom_up = height > 0  # a DIB with negative height is stored top-down
        self.width, self.height = int(width), abs(int(height))
        n_px = self.width * self.height
        if bi_compression == _BI_RGB:
            if bit_count not in (8, 16):
                raise self._error(f"unsupported pixel size {bit_count} bits", place="biBitCount")
            self.packing = "none"
            size_image = n_px * bit_count // 8
        elif bi_compression in (_BI_PACKED, _BI_PACKED_12):
            bits = size_image * 8 / n_px
            if bits not in (10.0, 12.0):
                raise self._error(f"packed images of {bits:g} bits per pixel are not supported",
                                  place="biSizeImage")
            self.packing = "10bit" if bits == 10 else "12bit"
        else:
            raise self._error(f"unsupported image compression biCompression={bi_compression}")
        self._image_bytes = int(size_image)
        self._bit_count = bit_count

        real_bpp = setup_u32(_SETUP_REAL_BPP)
        if self.packing != "none":
            self.bit_depth = 12  # 10-bit codes are expanded to linear 12-bit values
        elif bit_count == 8:
            self.bit_depth = 8
        else:
            self.bit_depth = real_bpp if real_bpp and 8 < real_bpp <= 16 else 16

        self.n_frames = int(count)
        self.first_image_no = int(first_no)
        table = self._read_at(off_offsets, 8 * count, "the table of image offsets")
        self._offsets = np.frombuffer(table, dtype="<u8").astype(np.int64)
        if self._offsets.min() < 0 or self._offsets.max() + 8 + self._image_bytes > self._size:
            bad = int(np.argmax((self._offsets < 0) |
                                (self._offsets + 8 + self._image_bytes > self._size)))
            raise self._error(f"truncated: image {bad} of {count} lies past the end of the file")

        self.time_stamps_s, self.exposure_s = self._read_tagged_blocks(off_setup + setup_len,
                                                                       off_offsets)
        rate = setup_u32(_SETUP_FRAME_RATE)
        if not rate:
            rate = _U16.unpack(self._read_at(off_setup + _SETUP_FRAME_RATE_16, 2, "SETUP"))[0]
        self.acquisition_fps = float(rate) if rate else None
        self.decimation = self._decimation()
        self.fps = None if self.acquisition_fps is None else self.acquisition_fps / self.decimation

    def _read_tagged_blocks(self, start: int, end: int):
        stamps = exposure = None
        pos = start
        while pos + _BLOCK.size <= end:
            size, kind, _ = _BLOCK.unpack(self._read_at(pos, _BLOCK.size, "a tagged block"))
            if size < _BLOCK.size or pos + size > end:
                break  # malformed or unknown trailer: the blocks are optional, stop here
            n_data = size - _BLOCK.size
            if kind == _TAG_TIME_ONLY and n_data == 8 * self.n_frames:
                raw = np.frombuffer(self._read_at(pos + 8, n_data, "time stamps"), "<u8")
                stamps = (raw >> np.uint64(32)).astype(np.float64) + \
                    (raw & np.uint64(0xFFFFFFFF)).astype(np.float64) / 2.0**32
            elif kind == _TAG_EXPOSURE and n_data == 4 * self.n_frames:
                raw = np.frombuffer(self._read_at(pos + 8, n_data, "exposures"), "<u4")
                exposure = raw.astype(np.float64) / 2.0**32
            pos += size
        return stamps, exposure

    def _decimation(self) -> int:
        if self.acquisition_fps is None or self.time_stamps_s is None or self.n_frames < 2:
            return 1
        dt = float(np.median(np.diff(self.time_stamps_s)))
        ratio = dt * self.acquisition_fps
        k = int(round(ratio))
        # time stamps are good to about 1e-7 s: accept only a clear integer multiple
        return k if k >= 2 and abs(ratio - k) < 0.02 * k else 1

    # -- frames ---------------------------------------------------------------------------
    def read(self, index: int) -> np.ndarray:
        """Frame `index` (0-based, in file order) as (height, width) uint8/uint16, row 0 on top.

        Values are grey levels of `bit_depth` bits. Raises IndexError out of range and
        InputError for a truncated or inconsistent frame.
        """
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range 0..{self.n_frames - 1}")
        start = int(self._offsets[index])
        annotation = _U32.unpack(self._read_at(start, 4, f"image {index}"))[0]
        if annotation < 8 or start + annotation + self._image_bytes > self._size:
            raise self._error(f"truncated or corrupt image {index} "
                              f"(annotation of {annotation} bytes)", place=f"frame {index}")
        data = self._read_at(start + annotation, self._image_bytes, f"image {index}")
        if self.packing == "10bit":
            img = LUT_10_TO_12[_unpack_10(data)]
        elif self.packing == "12bit":
            img = _unpack_12(data)
        else:
            img = np.frombuffer(data, dtype="u1" if self._bit_count == 8 else "<u2")
        img = img.reshape(self.height, self.width)
        if self.packing == "none" and self._bottom_up:
            img = img[::-1]
        return img

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "CineFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"CineFile({self.path!r}, {self.n_frames} frames {self.width}x{self.height}, "
                f"{self.bit_depth} bit, {self.fps} fps)")


def _unpack_10(data: bytes) -> np.ndarray:
    """Four 10-bit codes from each 5 bytes, most significant bits first."""
    b = np.frombuffer(data, dtype=np.uint8).reshape(-1, 5).astype(np.uint16)
    out = np.empty((b.shape[0], 4), dtype=np.uint16)
    out[:, 0] = (b[:, 0] << 2) | (b[:, 1] >> 6)
    out[:, 1] = ((b[:, 1] & 0x3F) << 4) | (b[:, 2] >> 4)
    out[:, 2] = ((b[:, 2] & 0x0F) << 6) | (b[:, 3] >> 2)
    out[:, 3] = ((b[:, 3] & 0x03) << 8) | b[:, 4]
    return out.ravel()


def _unpack_12(data: bytes) -> np.ndarray:
    """Two 12-bit values from each 3 bytes, most significant bits first."""
    b = np.frombuffer(data, dtype=np.uint8).reshape(-1, 3).astype(np.uint16)
    out = np.empty((b.shape[0], 2), dtype=np.uint16)
    out[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
    out[:, 1] = ((b[:, 1] & 0x0F) << 8) | b[:, 2]
    return out.ravel()

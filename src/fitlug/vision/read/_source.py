"""Frames from a video file, a folder (or list) of images or a Phantom .cine, read one at a time.

`open_source(source, fps=..., frames=...)` returns a `FrameSource`. Every source gives
2-D float32 grey frames in the grey levels of the original bit depth (0..255 for 8-bit
video and images, 0..4095 for a 12-bit cine, 0..65535 for 16-bit images), row 0 at the
top. Frames are read on demand, so memory does not grow with the length of the video.

Frame numbers are always those of the file (0 = its first frame), also after a `frames=`
selection: `len(src)` counts the selected frames, `src.indices` lists them, iteration
yields `(index, time_s, frame)` for each, and `src.frame(i)` reads any frame `i` of the
file. Times are `index / fps` seconds, so t = 0 at the file's first frame (never relative
to a camera trigger; a cine's trigger-relative numbering is kept in `CineFile`).
"""

from __future__ import annotations

import os
import re
import warnings
from typing import Iterator, Sequence

import numpy as np

from ..._errors import InputError

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")
FrameSelection = slice | range | Sequence[int] | tuple | None


class FrameSource:
    """Base of the readers; see the module docstring for the indexing rules.

    Attributes: `path` (str), `fps` (Hz), `shape` ((H, W) px), `bit_depth` (bits of the
    original grey levels), `n_file_frames` (frames in the file), `indices` (selected file
    frame numbers, int ndarray).
    """

    path: str
    fps: float
    shape: tuple[int, int]
    bit_depth: int
    n_file_frames: int
    indices: np.ndarray

    def _select(self, frames: FrameSelection) -> None:
        n = self.n_file_frames
        if frames is None:
            idx = np.arange(n)
        elif isinstance(frames, slice):
            idx = np.arange(n)[frames]
        elif isinstance(frames, tuple) and 1 <= len(frames) <= 3 and \
                all(f is None or isinstance(f, (int, np.integer)) for f in frames):
            idx = np.arange(n)[slice(*frames)]  # (start, stop[, step])
        else:
            idx = np.asarray(list(frames), dtype=np.int64).ravel()
            idx = np.where(idx < 0, idx + n, idx)
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise InputError(self.path, f"frame selection out of range 0..{n - 1}",
                                 place="frames")
        if idx.size == 0:
            raise InputError(self.path, f"the frame selection {frames!r} is empty "
                             f"(the source has {n} frames)", place="frames")
        self.indices = idx.astype(np.int64)

    def __len__(self) -> int:
        return int(self.indices.size)

    def times(self) -> np.ndarray:
        """Times of the selected frames, seconds, (len(self),): index / fps."""
        return self.indices / self.fps

    def frame(self, index: int) -> np.ndarray:
        """File frame `index` as (H, W) float32 grey levels. IndexError if out of range."""
        index = int(index)
        if index < 0:
            index += self.n_file_frames
        if not 0 <= index < self.n_file_frames:
            raise IndexError(f"{self.path}: frame {index} out of range 0..{self.n_file_frames - 1}")
        return self._read(index)

    def __iter__(self) -> Iterator[tuple[int, float, np.ndarray]]:
        for i in self.indices:
            yield int(i), float(i / self.fps), self._read(int(i))

    def _read(self, index: int) -> np.ndarray:
        raise NotImplementedError

    def close(self) -> None:
        """Release the file handles (also done by `with open_source(...) as src:`)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.path!r}, {len(self)} of {self.n_file_frames} "
                f"frames, {self.shape[1]}x{self.shape[0]} px, {self.bit_depth} bit, "
                f"{self.fps:g} fps)")


def _check_fps(path: str, fps: float | None, native: float | None) -> float:
    value = native if fps is None else fps
    if value is None:
        raise InputError(path, "the frame rate is not known: pass fps (frames per second)")
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(path, f"fps must be a number, got {value!r}", place="fps") from None
    if not np.isfinite(value) or value <= 0:
        raise InputError(path, f"fps must be a positive number, got {value!r}", place="fps")
    return value


def _to_grey(img: np.ndarray) -> np.ndarray:
    import cv2

    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img, code)  # keeps uint16 as uint16
    return img


class CineSource(FrameSource):
    """A Phantom .cine file (see `fitlug.vision.read._cine`); `cine` holds the header facts."""

    def __init__(self, path: str, fps: float | None, frames: FrameSelection):
        from ._cine import CineFile

        self.path = path
        self.cine = CineFile(path)
        try:
            self.fps = _check_fps(path, fps, self.cine.fps)
            self.shape = (self.cine.height, self.cine.width)
            self.bit_depth = self.cine.bit_depth
            self.n_file_frames = self.cine.n_frames
            self._select(frames)
        except BaseException:
            self.cine.close()
            raise

    def _read(self, index: int) -> np.ndarray:
        return self.cine.read(index).astype(np.float32)

    def close(self) -> None:
        self.cine.close()


class ImageListSource(FrameSource):
    """Image files (PNG/TIFF/JPEG/BMP), one frame each, in the order given.

    8- and 16-bit images keep their grey levels; colour images are converted to grey.
    Every frame must have the shape and bit depth of the first.
    """

    def __init__(self, path: str, files: Sequence[str], fps: float | None,
                 frames: FrameSelection):
        self.path = path
        self.files = [os.fspath(f) for f in files]
        if not self.files:
            raise InputError(path, "no image files (" + ", ".join(IMAGE_SUFFIXES) + ") found")
        self.fps = _check_fps(path, fps, None)
        self.n_file_frames = len(self.files)
        first = self._load(0)
        self.shape = first.shape
        self._dtype = first.dtype
        self.bit_depth = 8 * first.dtype.itemsize
        self._select(frames)

    def _load(self, index: int) -> np.ndarray:
        import cv2

        name = self.files[index]
        img = cv2.imread(name, cv2.IMREAD_UNCHANGED)
        if img is None:
            problem = "file not found" if not os.path.exists(name) else \
                "cannot be read as an image (corrupt or unsupported format)"
            raise InputError(name, problem)
        img = _to_grey(img)
        if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
            raise InputError(name, f"unsupported image: {img.dtype} with shape {img.shape} "
                             "(need 8- or 16-bit grey or colour)")
        return img

    def _read(self, index: int) -> np.ndarray:
        img = self._load(index)
        if img.shape != self.shape or img.dtype != self._dtype:
            raise InputError(self.files[index], f"frame {index} is {img.shape[1]}x{img.shape[0]} "
                             f"{img.dtype}, unlike the first frame ({self.shape[1]}x"
                             f"{self.shape[0]} {self._dtype})")
        return img.astype(np.float32)


class VideoSource(FrameSource):
    """A video file OpenCV can decode (AVI, MP4, MKV ...), converted to 8-bit grey.

    Iteration decodes sequentially (skipping unselected frames with `grab`); `frame(i)`
    seeks, which some codecs do only approximately, so prefer iteration.
    """

    def __init__(self, path: str, fps: float | None, frames: FrameSelection):
        import cv2

        self.path = path
        self._cap = cv2.VideoCapture(path)
        if not self._cap.isOpened():
            raise InputError(path, "cannot be opened as a video (corrupt, empty or unsupported "
                             "codec)")
        try:
            native = self._cap.get(cv2.CAP_PROP_FPS)
            self.fps = _check_fps(path, fps, native if native and np.isfinite(native) and
                                  native > 0 else None)
            ok, img = self._cap.read()
            if not ok or img is None:
                raise InputError(path, "no frame could be decoded (empty or corrupt video)")
            grey = _to_grey(img)
            self.shape = grey.shape
            self.bit_depth = 8 * grey.dtype.itemsize
            self._pos = 1  # index of the next frame `read` would return
            count = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            # some containers do not store the count: decode through once (grab only)
            self.n_file_frames = count if count > 0 else self._count_frames()
            self._select(frames)
        except BaseException:
            self._cap.release()
            raise

    def _count_frames(self) -> int:
        import cv2

        self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        n = 0
        while self._cap.grab():
            n += 1
        self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self._pos = 0
        return n

    def _seek(self, index: int) -> None:
        import cv2

        if index == self._pos:
            return
        if self._pos < index <= self._pos + 64:  # a short skip: decoding is exact
            while self._pos < index:
                if not self._cap.grab():
                    break
                self._pos += 1
            return
        self._cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        self._pos = index

    def _read(self, index: int) -> np.ndarray:
        self._seek(index)
        ok, img = self._cap.read()
        if not ok or img is None:
            raise InputError(self.path, f"frame {index} could not be decoded (the container "
                             f"claims {self.n_file_frames} frames)", place=f"frame {index}")
        self._pos = index + 1
        return _to_grey(img).astype(np.float32)

    def __iter__(self) -> Iterator[tuple[int, float, np.ndarray]]:
        for i in self.indices:
            try:
                frame = self._read(int(i))
            except InputError:
                if i == self.indices[0]:
                    raise
                # containers often overstate their frame count: stop at the real end
                warnings.warn(f"{self.path}: video ends at frame {i} although it claims "
                              f"{self.n_file_frames} frames", stacklevel=2)
                return
            yield int(i), float(i / self.fps), frame

    def close(self) -> None:
        self._cap.release()


def _natural_key(name: str):
    # "frame2.png" before "frame10.png": digits compare as numbers
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _image_files(folder: str) -> list[str]:
    names = [n for n in os.listdir(folder)
             if n.lower().endswith(IMAGE_SUFFIXES) and not n.startswith(".")]
    return [os.path.join(folder, n) for n in sorted(names, key=_natural_key)]


def open_source(source: str | os.PathLike | Sequence[str | os.PathLike], *,
                fps: float | None = None, frames: FrameSelection = None) -> FrameSource:
    """Open frames for streaming.

    source: a video file (read by OpenCV), a `.cine` file, a folder of images (PNG, TIFF,
        JPEG, BMP; sorted by name with numbers compared as numbers), or a list of image
        files (taken in the order given).
    fps: frame rate, Hz; overrides the file's. Required for folders and image lists.
    frames: which file frames to use: a slice, a (start, stop[, step]) tuple, or a list of
        frame numbers. Default: all.

    Returns a FrameSource (use it as a context manager to close the file). Raises
    InputError naming the source for a missing, unreadable, corrupt or empty source, an
    unknown frame rate, or an empty selection.
    """
    if isinstance(source, (list, tuple)):
        files = [os.fspath(f) for f in source]
        return ImageListSource(files[0] if files else "<image list>", files, fps, frames)
    path = os.fspath(source)
    if os.path.isdir(path):
        return ImageListSource(path, _image_files(path), fps, frames)
    if not os.path.exists(path):
        raise InputError(path, "no such file or folder")
    if os.path.getsize(path) == 0:
        raise InputError(path, "the file is empty")
    if path.lower().endswith(".cine"):
        return CineSource(path, fps, frames)
    if path.lower().endswith(IMAGE_SUFFIXES):
        raise InputError(path, "a single image is not a video: pass the folder of frames "
                         "(or a list of image files)")
    return VideoSource(path, fps, frames)

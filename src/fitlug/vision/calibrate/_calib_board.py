"""Calibration boards: parsing `chessboard:9x6` / `charuco:5x7` and finding their corners.

Chessboard sizes count INNER corners (columns x rows), as OpenCV does; ChArUco sizes
count SQUARES (x by y). Board coordinates are in mm, in the board plane (z = 0).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_SPEC = re.compile(r"^\s*(chessboard|charuco)\s*:\s*(\d+)\s*[xX×]\s*(\d+)\s*$")


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    kind: "chessboard" or "charuco". cols, rows: inner corners (chessboard) or squares
    (charuco). square_mm: side of a square, mm. marker_mm, dictionary: ChArUco only
    (marker side in mm, OpenCV dictionary name such as "DICT_6X6_250").
    """

    kind: str
    cols: int
    rows: int
    square_mm: float
    marker_mm: float | None = None
    dictionary: str | None = None

    @property
    def spec(self) -> str:
        return f"{self.kind}:{self.cols}x{self.rows}"

    def describe(self) -> str:
        text = f"{self.spec}, {self.square_mm:g} mm squares"
        if self.kind == "charuco":
            text += f", {self.marker_mm:g} mm markers, {self.dictionary}"
        return text

    def corner_grid(self) -> tuple[int, int]:
        """(columns, rows) of the grid of corners the detector returns."""
        if self.kind == "chessboard":
            return self.cols, self.rows
        return self.cols - 1, self.rows - 1

    def opencv_charuco(self):
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_mm, self.marker_mm,
                                      dictionary)


def parse_board(spec: str | Board, square_mm: float, marker_mm: float | None = None,
                dictionary: str | None = None) -> Board:
    """Board from a spec such as "chessboard:9x6" or "charuco:5x7".

    Raises ValueError naming the argument and the fix for a malformed spec, non-positive
    sizes, or a ChArUco board without marker size or with an unknown dictionary.
    """
    if isinstance(spec, Board):
        return spec
    m = _SPEC.match(str(spec))
    if not m:
        raise ValueError(f"board {spec!r} not understood: use 'chessboard:COLSxROWS' (inner "
                         "corners) or 'charuco:XxY' (squares), e.g. chessboard:9x6")
    kind, cols, rows = m.group(1), int(m.group(2)), int(m.group(3))
    try:
        square_mm = float(square_mm)
    except (TypeError, ValueError):
        raise ValueError(f"square_mm must be a number, got {square_mm!r}") from None
    if not np.isfinite(square_mm) or square_mm <= 0:
        raise ValueError(f"square_mm must be a positive size in mm, got {square_mm!r}")
    if kind == "chessboard":
        if cols < 2 or rows < 2:
            raise ValueError(f"board {spec!r}: a chessboard needs at least 2x2 inner corners")
        return Board(kind, cols, rows, square_mm)
    import cv2

    if cols < 2 or rows < 2 or cols * rows < 6:
        raise ValueError(f"board {spec!r}: a ChArUco board needs at least 2x3 squares")
    if marker_mm is None or not 0 < float(marker_mm) < square_mm:
        raise ValueError(f"a ChArUco board needs marker_mm (marker side, mm) smaller than the "
                         f"square ({square_mm:g} mm), got {marker_mm!r}")
    dictionary = dictionary or "DICT_6X6_250"
    if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
        raise ValueError(f"unknown ArUco dictionary {dictionary!r}: use an OpenCV name such "
                         "as DICT_6X6_250, DICT_5X5_100, DICT_4X4_50")
    return Board(kind, cols, rows, square_mm, float(marker_mm), dictionary)


def _subpix_half_window(corners: np.ndarray, grid: tuple[int, int]) -> int:
    # cornerSubPix uses every gradient in a (2w+1)^2 window; a window that reaches the
    # neighbouring corners biases the result (OpenCV's sample window of w = 11 does so on
    # its own left02 view, whose nearest corners are 22 px apart). Keep w at 0.3 of the
    # smallest corner spacing.
    cols, rows = grid
    xy = corners.reshape(rows, cols, 2)
    gaps = np.concatenate([np.linalg.norm(np.diff(xy, axis=1), axis=2).ravel(),
                           np.linalg.norm(np.diff(xy, axis=0), axis=2).ravel()])
    return int(np.clip(round(0.3 * float(gaps.min())), 2, 11))


def detect_corners(board: Board, grey: np.ndarray, subpix_window: int | None = None):
    """Corners of `board` in an 8-bit grey image.

    Returns (object_mm (N, 3) float32, image_px (N, 1, 2) float32, ids (N,) int) or, when
    the board is not found, (None, None, reason). `subpix_window` is cornerSubPix's
    half-window in px for chessboards (default: 0.3 x the smallest corner spacing, at
    most 11; OpenCV's calibration sample uses 11).
    """
    import cv2

    if board.kind == "chessboard":
        pattern = (board.cols, board.rows)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(grey, pattern, flags=flags)
        if not found:
            return None, None, f"no {board.cols}x{board.rows} chessboard found"
        w = subpix_window or _subpix_half_window(corners, pattern)
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
        corners = cv2.cornerSubPix(grey, corners, (w, w), (-1, -1), criteria)
        obj = np.zeros((board.cols * board.rows, 3), np.float32)
        obj[:, :2] = np.mgrid[0:board.cols, 0:board.rows].T.reshape(-1, 2) * board.square_mm
        return obj, corners.astype(np.float32), np.arange(len(obj))
    cb = board.opencv_charuco()
    detector = cv2.aruco.CharucoDetector(cb)
    ch_corners, ch_ids, _, marker_ids = detector.detectBoard(grey)
    n = 0 if ch_ids is None else len(ch_ids)
    if n < 6:
        markers = 0 if marker_ids is None else len(marker_ids)
        return None, None, (f"only {n} ChArUco corners found ({markers} markers; need 6): "
                            "check --board, --dict and the marker size")
    if cb.checkCharucoCornersCollinear(ch_ids):
        return None, None, "the ChArUco corners found lie on one line"
    obj, img = cb.matchImagePoints(ch_corners, ch_ids)
    return obj.reshape(-1, 3).astype(np.float32), img.reshape(-1, 1, 2).astype(np.float32), \
        ch_ids.ravel().astype(int)

"""DeepLabCut analysis outputs: CSV (3 or 4 header rows) and .h5 (pandas, key df_with_missing).

The table has one row per frame (the index: frame number from 0) and a column MultiIndex
`scorer / [individuals /] bodyparts / coords` with coords x, y, likelihood; positions in
pixels, origin top-left, y down; multi-animal files leave missing cells empty. No time or
fps is written. A sample whose likelihood is below the threshold is treated as missing
(DeepLabCut's own `pcutoff` default, 0.6, is ours); the likelihood is kept as `quality`.

The CSV is read with the csv module (line numbers for errors). The .h5 is a pandas
HDFStore table and needs pandas with PyTables (`pip install 'fitlug[trackers]'`).
"""

from __future__ import annotations

import csv
import io

import numpy as np

from .._errors import InputError
from ._imported import Tracks, number, read_text

DEFAULT_LIKELIHOOD = 0.6  # DeepLabCut's default pcutoff (config.yaml)


def _check_threshold(likelihood: float) -> float:
    if not (np.isfinite(likelihood) and 0.0 <= likelihood <= 1.0):
        raise InputError("--likelihood", f"must be between 0 and 1, got {likelihood!r}")
    return float(likelihood)


def from_columns(path: str, columns: list[tuple[str, ...]], levels: list[str],
                 index: list, values: np.ndarray, likelihood: float, fmt: str,
                 lines: list[int] | None = None) -> Tracks:
    """Tracks from DeepLabCut's column tuples (one per column, levels named by `levels`),
    the index (frame numbers) and the (F, C) values."""
    likelihood = _check_threshold(likelihood)
    lv = {name: k for k, name in enumerate(levels)}
    for need in ("bodyparts", "coords"):
        if need not in lv:
            raise InputError(path, f"no {need!r} header row: not a DeepLabCut table", line=1)
    parts: dict[tuple[str, str], dict[str, int]] = {}
    for j, col in enumerate(columns):
        ind = col[lv["individuals"]] if "individuals" in lv else ""
        parts.setdefault((ind, col[lv["bodyparts"]]), {})[col[lv["coords"]]] = j
    bodyparts = [bp for _, bp in parts]
    names = [bp if bodyparts.count(bp) == 1 else f"{ind}.{bp}" for ind, bp in parts]
    f = values.shape[0]
    xy = np.full((f, len(parts), 2), np.nan)
    quality = np.full((f, len(parts)), np.nan)
    for m, (key, c) in enumerate(parts.items()):
        if "x" not in c or "y" not in c:
            raise InputError(path, f"body part {key[1]} has no x or y column", line=1)
        xy[:, m, 0], xy[:, m, 1] = values[:, c["x"]], values[:, c["y"]]
        if "likelihood" in c:
            quality[:, m] = values[:, c["likelihood"]]
    low = ~(quality >= likelihood) & np.isfinite(quality)
    xy[low] = np.nan
    try:
        frame = np.array([int(v) for v in index], dtype=np.int64)
    except (TypeError, ValueError):
        frame = np.arange(f, dtype=np.int64)  # labelled-data tables index by image path
    if np.any(np.diff(frame) <= 0):
        k = int(np.flatnonzero(np.diff(frame) <= 0)[0])
        raise InputError(path, f"frame numbers not increasing: {frame[k + 1]} after {frame[k]}",
                         line=None if lines is None else lines[k + 1])
    return Tracks(fmt, path, tuple(names), frame, xy_px=xy,
                  quality=quality if np.isfinite(quality).any() else None,
                  meta={"likelihood_threshold": f"{likelihood:g}",
                        "below_threshold": str(int(low.sum()))})


def read_dlc_csv(path: str, likelihood: float = DEFAULT_LIKELIHOOD) -> Tracks:
    """A DeepLabCut CSV: header rows scorer, [individuals,] bodyparts, coords; pixels."""
    rows = list(csv.reader(io.StringIO(read_text(path))))
    numbered = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    levels, heads = [], []
    for no, r in numbered:
        key = r[0].strip()
        if key in ("scorer", "individuals", "bodyparts", "coords"):
            levels.append(key)
            heads.append(r[1:])
            if key == "coords":
                break
        else:
            break
    if not levels or levels[0] != "scorer" or levels[-1] != "coords":
        raise InputError(path, "a DeepLabCut CSV starts with the header rows scorer, "
                               "[individuals,] bodyparts, coords", line=1)
    width = len(heads[0])
    if any(len(h) != width for h in heads):
        raise InputError(path, "the header rows have different lengths", line=len(heads))
    columns = list(zip(*[[c.strip() for c in h] for h in heads]))
    data = numbered[len(levels):]
    if not data:
        raise InputError(path, "no rows below the header", line=len(levels))
    values = np.full((len(data), width), np.nan)
    index, lines = [], []
    for i, (no, r) in enumerate(data):
        if len(r) - 1 < width:
            raise InputError(path, f"row has {len(r)} fields, the header has {width + 1}",
                             line=no)
        index.append(r[0])
        lines.append(no)
        for j in range(width):
            try:
                values[i, j] = number(r[j + 1])
            except ValueError:
                raise InputError(path, f"column {'/'.join(columns[j][1:])}: {r[j + 1]!r} is "
                                       f"not a number", line=no) from None
    return from_columns(path, columns, levels, index, values, likelihood, "deeplabcut", lines)


def tracks_from_dlc_frame(df, path: str, likelihood: float, fmt: str) -> Tracks:
    """Tracks from a DeepLabCut pandas DataFrame (MultiIndex columns)."""
    names = [n or "" for n in df.columns.names]
    columns = [tuple(str(v) for v in c) for c in df.columns]
    values = np.asarray(df.to_numpy(dtype=np.float64, na_value=np.nan))
    return from_columns(path, columns, names, list(df.index), values, likelihood, fmt)


def read_dlc_h5(path: str, likelihood: float = DEFAULT_LIKELIHOOD) -> Tracks:
    """A DeepLabCut .h5 (pandas HDFStore); needs pandas and PyTables."""
    try:
        import pandas as pd
        import tables  # noqa: F401  (pandas.read_hdf needs it)
    except ImportError:
        raise InputError(path, "reading DeepLabCut .h5 files needs pandas and PyTables: "
                               "pip install 'fitlug[trackers]' (or read the .csv twin DeepLabCut "
                               "writes with save_as_csv=True)") from None
    try:
        with pd.HDFStore(path, mode="r") as store:
            keys = store.keys()
            key = "/df_with_missing" if "/df_with_missing" in keys else (keys[0] if keys else None)
            if key is None:
                raise InputError(path, "the HDF5 file holds no pandas table")
            df = store[key]
    except InputError:
        raise
    except Exception as exc:  # PyTables/pandas raise many kinds for a broken file
        raise InputError(path, f"cannot read as a pandas HDF5 table: {exc}") from None
    if getattr(df.columns, "nlevels", 1) < 3:
        raise InputError(path, f"table {key} has no scorer/bodyparts/coords columns: not a "
                               "DeepLabCut output", place=key)
    return tracks_from_dlc_frame(df, path, likelihood, "deeplabcut-h5")

"""fit.json and other JSON outputs: strict JSON (NaN/inf become null), written atomically."""

from __future__ import annotations

import json
import math
import os
import pathlib
from typing import Any

import numpy as np

from .._errors import InputError
from ._atomic import write_text_atomic


def _plain(obj: Any, where: str) -> Any:
    """`obj` as plain JSON types: numpy scalars/arrays -> Python, NaN/inf -> None."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _plain(v, f"{where}.{k}" if where else str(k)) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, pathlib.PurePath):
        return str(obj)
    if isinstance(obj, np.generic) or hasattr(obj, "__array__"):  # numpy, also JAX arrays
        array = np.asarray(obj)
        if array.dtype.kind not in "biuf":
            raise TypeError(f"cannot write {where or 'value'} of dtype {array.dtype} to JSON")
        return _plain(array.tolist(), where)
    raise TypeError(f"cannot write {where or 'value'} of type {type(obj).__name__} to JSON")


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write `obj` to `path` as pretty (indent 2) strict JSON, atomically.

    numpy scalars and arrays (and anything with `__array__`) become numbers and lists;
    NaN and infinities become null; tuples become lists; dict keys become strings.

    Raises:
        TypeError: a value JSON cannot hold (the message gives its place, e.g. 'slip.value').
    """
    text = json.dumps(_plain(obj, ""), indent=2, allow_nan=False, ensure_ascii=False)
    write_text_atomic(path, text + "\n")


def _refuse_constant(name: str):
    raise ValueError(f"non-standard JSON constant {name}")


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file (strict: NaN/Infinity are refused).

    Raises:
        InputError: missing/unreadable file or bad JSON, with line and column.
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not a JSON file") from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"invalid JSON: {exc.msg}", line=exc.lineno,
                         place=f"column {exc.colno}") from None
    except ValueError as exc:
        raise InputError(path, f"invalid JSON: {exc}") from None

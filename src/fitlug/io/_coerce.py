"""What the library's entry points accept as a recording or a rig, turned into the real
objects before any work (and before JAX is imported): a Recording, a pandas DataFrame, a
path to a trajectory file; a Rig, a dict of Rig fields, a path to rig.toml. Anything else
is a one-line TypeError saying what is accepted."""

from __future__ import annotations

import dataclasses
import os

from ._recording import Recording


def as_recording(obj, *, rig=None) -> Recording:
    """`obj` as a Recording: a Recording as it is, a pandas DataFrame through
    :meth:`Recording.from_dataframe` (roles from `rig`), a path through
    :func:`fitlug.io.read_any` (any supported format; trajectories.csv by default).

    Raises:
        TypeError: anything else (naming its type and what is accepted).
        InputError: an unreadable file or table.
    """
    if isinstance(obj, Recording):
        return obj
    if _is_dataframe(obj):
        return Recording.from_dataframe(obj, rig=rig)
    if isinstance(obj, (str, os.PathLike)):
        from ._formats import read_any

        return read_any(obj, rig=rig)
    raise TypeError(f"recording: expected a fitlug.io.Recording, a pandas DataFrame or the "
                    f"path of a trajectory file, got {type(obj).__name__}")


def rig_fields() -> list[str]:
    """The keyword names of :class:`fitlug.io.Rig` (what a dict rig may hold)."""
    from ._rig import Rig

    return [f.name for f in dataclasses.fields(Rig) if f.name not in ("path", "assumed")]


def as_rig(obj):
    """`obj` as a Rig: None and a Rig as they are, a dict through ``Rig(**d)`` (its keys
    checked against the Rig's fields), a path through :func:`fitlug.io.read_rig`.

    Raises:
        TypeError: another type, or a dict key that is no Rig field (naming the valid ones).
        InputError: a value out of range, an unreadable rig file.
    """
    from ._rig import Rig, read_rig

    if obj is None or isinstance(obj, Rig):
        return obj
    if isinstance(obj, dict):
        names = rig_fields()
        bad = [k for k in obj if k not in names]
        if bad:
            raise TypeError(f"rig: unknown field {bad[0]!r}; a rig dict takes "
                            f"{', '.join(names)}")
        return Rig(**obj)
    if isinstance(obj, (str, os.PathLike)):
        return read_rig(obj)
    raise TypeError(f"rig: expected a fitlug.io.Rig, a dict of its fields or the path of "
                    f"rig.toml, got {type(obj).__name__}")


def _is_dataframe(obj) -> bool:
    mod = type(obj).__module__ or ""
    return mod.startswith("pandas") and type(obj).__name__ == "DataFrame"


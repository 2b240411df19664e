"""A campaign's sources: CSV paths (their rig.toml beside them), folders, glob patterns
and Recording objects, expanded into checked `Source`s (one track: same n and L, every
mass given; unique output names).
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass

from .._errors import InputError


@dataclass
class Source:
    """One recording to fit: a CSV path (and its rig), or a Recording object."""

    name: str
    csv: str | None
    rig: object
    recording: object = None


# -- sources ----------------------------------------------------------------------------

def _rig_beside(csv: str) -> str | None:
    folder = os.path.dirname(os.path.abspath(csv))
    stem = os.path.splitext(os.path.basename(csv))[0]
    for name in (f"{stem}.rig.toml", "rig.toml"):
        p = os.path.join(folder, name)
        if os.path.isfile(p):
            return p
    return None


def _csvs_in(folder: str) -> list[str]:
    out = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        out += [os.path.join(root, f) for f in sorted(files)
                if f.lower().endswith(".csv") and not f.startswith(".")]
    return out


def _name(csv: str, root: str | None) -> str:
    stem = os.path.splitext(os.path.basename(csv))[0]
    parent = os.path.basename(os.path.dirname(os.path.abspath(csv)))
    return parent if stem == "trajectories" and parent else stem


def resolve_sources(sources) -> list[Source]:
    """Expand paths, folders and globs (and Recording objects) into checked sources.

    Raises:
        InputError: a path that does not exist, a folder or pattern without a CSV, a
            recording without rig.toml or without mass, mixed n or L (one line each).
    """
    from ..io import Recording, Rig, read_rig

    if isinstance(sources, (str, os.PathLike)) or isinstance(sources, Recording):
        sources = [sources]
    items: list[Source] = []
    for src in sources:
        if isinstance(src, tuple) and len(src) == 2 and isinstance(src[0], Recording):
            rec, rig = src
            items.append(Source(name=_rec_name(rec, len(items)), csv=rec.path, rig=rig,
                                recording=rec))
            continue
        if isinstance(src, Recording):
            if src.path and _rig_beside(src.path):
                rig = read_rig(_rig_beside(src.path))
            else:
                raise InputError(src.path or f"recording {len(items) + 1}",
                                 "a Recording without its rig: pass (recording, rig)")
            items.append(Source(name=_rec_name(src, len(items)), csv=src.path, rig=rig,
                                recording=src))
            continue
        path = os.fspath(src)
        if any(c in path for c in "*?["):
            matches = sorted(glob.glob(path, recursive=True))
            csvs = [c for m in matches for c in (_csvs_in(m) if os.path.isdir(m) else [m])
                    if c.lower().endswith(".csv")]
            if not csvs:
                raise InputError(path, "the pattern matches no trajectories CSV")
        elif os.path.isdir(path):
            csvs = _csvs_in(path)
            if not csvs:
                raise InputError(path, "no trajectories CSV in this folder (nor below it)")
        elif os.path.isfile(path):
            csvs = [path]
        else:
            raise InputError(path, "no such file or folder")
        for csv in csvs:
            rig_path = _rig_beside(csv)
            if rig_path is None:
                raise InputError(csv, "no rig.toml beside it: a campaign needs each "
                                      "recording's rig (mass, drawbar pull, ground)")
            items.append(Source(name=_name(csv, path), csv=csv, rig=read_rig(rig_path)))
    if not items:
        raise InputError(None, "no recordings given")
    _check(items)
    return items


def _rec_name(rec, i: int) -> str:
    if rec.path:
        return _name(rec.path, None)
    return f"recording_{i + 1:02d}"


def _check(items: list[Source]) -> None:
    first = items[0]
    seen: dict[str, int] = {}
    for s in items:
        where = getattr(s.rig, "path", None) or s.csv or s.name
        if s.rig.mass_kg is None:
            raise InputError(where, "[vehicle] mass_kg is missing: a campaign needs every "
                                    "recording's mass (its traction m C_rr g + F_d)")
        for attr, key in (("lugs_in_contact", "[track] lugs_in_contact"),
                          ("load_bearing_length_mm", "[track] load_bearing_length_mm")):
            a, b = getattr(s.rig, attr), getattr(first.rig, attr)
            if a != b:
                raise InputError(where, f"{key} = {a:g} differs from {b:g} of {first.name}: a "
                                        "campaign is one track (same n and L)")
        # unique output folder names
        if s.name in seen:
            seen[s.name] += 1
            s.name = f"{s.name}_{seen[s.name]}"
        else:
            seen[s.name] = 1

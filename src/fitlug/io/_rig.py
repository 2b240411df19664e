"""rig.toml (DATA.md): what is known about the robot and the camera."""

from __future__ import annotations

import datetime
import json
import math
import os
import re
import tomllib
from dataclasses import dataclass, field

from .._errors import InputError
from ._atomic import write_text_atomic
from ._files import read_bytes
from ._rig_check import check_keys


class _Bad(Exception):
    """A value that fails its check; the message is the rest of the sentence after the key."""


def _positive(value) -> float:
    try:
        ok = (not isinstance(value, bool) and isinstance(value, (int, float))
              and math.isfinite(value) and value > 0)
        number = float(value) if ok else None
    except OverflowError:  # an integer beyond float64
        raise _Bad(f"= {value} is beyond any plausible range") from None
    if number is None:
        raise _Bad(f"must be a number > 0, got {value!r}")
    return number


def _within(lo: float, hi: float, unit: str):
    """A check: a number > 0 within the plausible range [lo, hi] (a value outside it is
    most likely a typo or another unit, and would break the fit far from here)."""
    def check(value) -> float:
        value = _positive(value)
        if not lo <= value <= hi:
            raise _Bad(f"= {value:g} {unit} is outside the plausible range {lo:g} to {hi:g} "
                       f"{unit}".replace("  ", " "))
        return value
    return check


def _lug_count(value) -> int:
    try:
        ok = (not isinstance(value, bool) and isinstance(value, (int, float))
              and math.isfinite(value) and float(value).is_integer() and value >= 2)
    except OverflowError:  # an integer beyond float64
        raise _Bad(f"= {value} is outside the plausible range 2 to 1000 lugs") from None
    if not ok:
        raise _Bad(f"must be an integer >= 2, got {value!r}")
    if value > 1000:
        raise _Bad(f"= {value:g} is outside the plausible range 2 to 1000 lugs")
    return int(value)


def _pull(value) -> float:
    # a push from behind (a pusher rig, a trailer running downhill) is a negative pull:
    # the track's traction m C_rr g + F_d is smaller, and so is its slip
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise _Bad(f"must be a number (newtons; negative: pushed), got {value!r}")
    return float(value)


def _ground(value) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _Bad(f"must be a non-empty string, got {value!r}")
    return value.strip()


def _names(value) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)) or \
            not all(isinstance(v, str) and v.strip() for v in value):
        raise _Bad(f"must be a list of marker names, got {value!r}")
    names = tuple(v.strip() for v in value)
    if len(set(names)) != len(names):
        raise _Bad(f"lists a marker twice: {value!r}")
    return names


# (table, key, Rig attribute, check)
_FIELDS = (
    ("track", "load_bearing_length_mm", "load_bearing_length_mm", _within(1.0, 1e5, "mm")),
    ("track", "lugs_in_contact", "lugs_in_contact", _lug_count),
    ("track", "lug_pitch_mm", "lug_pitch_mm", _within(0.1, 1e4, "mm")),
    ("vehicle", "mass_kg", "mass_kg", _within(1e-3, 1e6, "kg")),
    ("vehicle", "drawbar_pull_N", "drawbar_pull_N", _pull),
    ("ground", "name", "ground", _ground),
    ("markers", "body", "body_markers", _names),
    ("markers", "lug", "lug_markers", _names),
    ("camera", "fps", "fps", _within(0.01, 1e8, "frames/s")),
)
_TABLES = ("track", "vehicle", "ground", "markers", "camera")


@dataclass(frozen=True)
class Rig:
    """Known facts about the rig (defaults: the reference robot).

    Attributes:
        load_bearing_length_mm: L, length of the load-bearing segment, mm (1 to 1e5).
        lugs_in_contact: n, lugs in contact with the ground (integer, 2 to 1000).
        lug_pitch_mm: p, lug pitch, mm (0.1 to 1e4), or None (then fitted).
        mass_kg: mass carried by this track, kg (1e-3 to 1e6), or None (stiffness then
            not identifiable).
        drawbar_pull_N: F_d, a known horizontal load the track pulls, N (default 0;
            negative where the track is pushed).
        ground: the ground's name ([ground] name), or None; recordings of one campaign on
            one ground share C_rr (and F_max).
        body_markers, lug_markers: marker ids by role, for wide-form trajectory files.
        fps: camera frame rate, 1/s ([camera] fps, 0.01 to 1e8), or None.
        extra: every other table/key of rig.toml, kept as read ({table: {key: value}}).
        path: the file it was read from (not part of equality).
        assumed: True where no rig was given and the reference robot's values stand in for
            it (`find_rig` without a rig.toml, a fit without a rig; not part of equality):
            the report then sets no slip against the reference paper's.

    Raises:
        InputError: a value out of range, naming the key (e.g. "[track] lugs_in_contact ...").
    """

    load_bearing_length_mm: float = 127.0
    lugs_in_contact: int = 8
    lug_pitch_mm: float | None = None
    mass_kg: float | None = None
    drawbar_pull_N: float = 0.0
    ground: str | None = None
    body_markers: tuple[str, ...] = ()
    lug_markers: tuple[str, ...] = ()
    fps: float | None = None
    extra: dict = field(default_factory=dict, hash=False)
    path: str | None = field(default=None, compare=False)
    assumed: bool = field(default=False, compare=False)

    def __post_init__(self):
        for table, key, attr, check in _FIELDS:
            value = getattr(self, attr)
            if value is None:
                continue
            try:
                object.__setattr__(self, attr, check(value))
            except _Bad as exc:
                raise InputError(self.path, f"[{table}] {key} {exc}") from None
        both = sorted(set(self.body_markers) & set(self.lug_markers))
        if both:
            raise InputError(self.path, f"[markers] marker {both[0]} is listed both as body "
                                        "and as lug")
        object.__setattr__(self, "extra", dict(self.extra))

    @classmethod
    def reference(cls, assumed: bool = False) -> "Rig":
        """The reference robot: the defaults, with lug pitch 18.36 mm (`assumed`: standing
        in for a rig nobody gave)."""
        return cls(lug_pitch_mm=18.36, assumed=assumed)


def _key_line(text: str, table: str | None, key: str) -> int | None:
    """Line number of `key = ...` inside `[table]` (None: top level), or None if not found."""
    current = None
    key_re = re.compile(r"""^\s*(?:%s|"%s"|'%s')\s*=""" % ((re.escape(key),) * 3))
    for number, line in enumerate(text.splitlines(), 1):
        header = re.match(r"^\s*\[\[?\s*([^\[\]]+?)\s*\]\]?\s*(#.*)?$", line)
        if header:
            current = header.group(1).strip().strip("\"'")
        elif current == table and key_re.match(line):
            return number
    return None


def read_rig(path: str | os.PathLike) -> Rig:
    """Read rig.toml. Missing keys keep their defaults; unknown tables go to `Rig.extra`.

    Unknown keys inside the known tables are kept in `extra` too ({table: {key: value}}),
    with a warning; a known key outside its table, or one that looks like a misspelt
    known key, is refused (fitlug.io._rig_check).

    Raises:
        InputError: unreadable file, TOML syntax error (with its line), or a bad value
            (naming the table, key and line), a known key outside its table or a
            near-miss of one (`mass = 10` for mass_kg).
    """
    path = os.fspath(path)
    data = read_bytes(path, "TOML file")
    try:
        text = data.decode("utf-8-sig")  # a BOM (Windows editors) as the CSV reader
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        where = re.search(r"\s*\(at line (\d+), column (\d+)\)", message)
        line = int(where.group(1)) if where else None
        problem = message[:where.start()] if where else message
        raise InputError(path, f"invalid TOML: {problem}", line=line) from None

    known = {(table, key): (attr, check) for table, key, attr, check in _FIELDS}
    check_keys(path, data, known, _TABLES, lambda table, key: _key_line(text, table, key))
    values: dict = {}
    extra: dict = {}
    for table, content in data.items():
        if table not in _TABLES:
            extra[table] = content
            continue
        if not isinstance(content, dict):
            raise InputError(path, f"[{table}] must be a table, got {content!r}",
                             line=_key_line(text, None, table))
        for key, value in content.items():
            if (table, key) not in known:
                extra.setdefault(table, {})[key] = value  # warned by check_keys
                continue
            attr, check = known[(table, key)]
            try:
                values[attr] = check(value)
            except _Bad as exc:
                raise InputError(path, f"[{table}] {key} {exc}",
                                 line=_key_line(text, table, key)) from None
    try:
        return Rig(**values, extra=extra, path=path)
    except InputError as exc:  # a rule across keys (a marker in both lists)
        raise InputError(path, exc.problem, line=_key_line(text, "markers", "lug")) from None


# -- writing --------------------------------------------------------------------------------

def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_value(key)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        # a JSON string is a TOML basic string, except that TOML forbids a raw DEL
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (datetime.datetime, datetime.date, datetime.time)):
        return value.isoformat()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_key(str(k))} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    raise TypeError(f"cannot write a value of type {type(value).__name__} to TOML: {value!r}")


def write_rig(path: str | os.PathLike, rig: Rig) -> None:
    """Write `rig` as rig.toml, atomically: [track], [vehicle], [markers], [camera], then
    the tables kept in `rig.extra`. Keys whose value is None are left out.

    Raises:
        TypeError: a value in `rig.extra` that TOML cannot hold.
    """
    tables: dict[str, dict] = {table: {} for table in _TABLES}
    for table, key, attr, _ in _FIELDS:
        value = getattr(rig, attr)
        if value is not None and value != () and not (attr == "drawbar_pull_N" and value == 0):
            tables[table][key] = list(value) if isinstance(value, tuple) else value
    top: dict = {}
    for name, content in rig.extra.items():
        if isinstance(content, dict):
            tables.setdefault(name, {}).update(content)
        else:
            top[name] = content  # a top-level key must come before any table
    out = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in top.items()]
    for name, content in tables.items():
        if not content:
            continue
        if out:
            out.append("")
        out.append(f"[{_toml_key(name)}]")
        out.extend(f"{_toml_key(str(k))} = {_toml_value(v)}" for k, v in content.items())
    write_text_atomic(path, "\n".join(out) + "\n")


def find_rig(csv_path: str | os.PathLike) -> Rig:
    """The rig for a trajectories file: `<stem>.rig.toml` or `rig.toml` beside it (first
    found, read with `read_rig`), else `Rig.reference(assumed=True)`."""
    csv_path = os.fspath(csv_path)
    folder = os.path.dirname(os.path.abspath(csv_path))
    stem = os.path.splitext(os.path.basename(csv_path))[0]
    for name in (f"{stem}.rig.toml", "rig.toml"):
        candidate = os.path.join(folder, name)
        if os.path.isfile(candidate):
            return read_rig(candidate)
    return Rig.reference(assumed=True)

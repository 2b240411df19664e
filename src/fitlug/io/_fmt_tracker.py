"""Open Source Physics Tracker: .trk (XML), .trz (a zip holding the .trk) and "Export Data" text.

A .trk is the XML of a `TrackerPanel`. Each point track (`...tracker.PointMass`) has a
`framedata` array indexed by frame number whose entries hold `x`, `y` in image pixels
(origin top-left, y down); unmarked frames are absent. The panel's `ImageCoordSystem`
holds, per key frame, the origin (px), the angle of the world x axis counter-clockwise
from the image x axis (degrees in the XML) and the scales (px per world unit); OSP's
`ImageCoordSystem.updateTransforms` maps world to image as

    x_img = sx cos(a) X - sx sin(a) Y + x0,    y_img = -sy sin(a) X - sy cos(a) Y + y0,

so the world point is (X, Y) = R(-a) ((x_img - x0) / sx, -(y_img - y0) / sy), y up, in
`length_unit`. A component fixed over time ("fixedorigin" ...) takes frame 0's value; a
varying one holds each key frame's value until the next. Time of frame n:
starttime + (n - startframe) * delta_t (ms).

Export Data text: the track name (spaces as '_'), or a `#multi:` line and a row of track
names over their columns; a row of column names (`t`, then `x`, `y`, ... per track); one row
per step; any delimiter, the locale's decimal separator, empty cells where unmarked. Its
world unit is not written: `length_unit` must be given.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
import zipfile

import numpy as np

from .._errors import InputError
from ._imported import Tracks, length_factor, number, read_text

_PANEL = "org.opensourcephysics.cabrillo.tracker.TrackerPanel"
_POINT_MASS = "org.opensourcephysics.cabrillo.tracker.PointMass"
_INDEX = re.compile(r"^\[(\d+)\]$")


def _props(obj: ET.Element) -> dict[str, ET.Element]:
    return {p.get("name"): p for p in obj.findall("property")}


def _value(prop: ET.Element | None, path: str, what: str):
    if prop is None:
        return None
    kind, text = prop.get("type"), (prop.text or "").strip()
    try:
        if kind == "double":
            return float(text)
        if kind == "int":
            return int(text)
        if kind == "boolean":
            return text == "true"
    except ValueError:
        raise InputError(path, f"{text!r} is not a {kind}", place=what) from None
    if kind == "object":
        return prop.find("object")
    return text


def _get(obj: ET.Element | None, name: str, path: str, what: str = ""):
    if obj is None:
        return None
    return _value(_props(obj).get(name), path, f"{what}{name}")


def _indexed(array: ET.Element | None) -> dict[int, ET.Element]:
    """The entries of an XML array property: index -> its <object>."""
    out = {}
    if array is None:
        return out
    for p in array.findall("property"):
        m = _INDEX.match(p.get("name") or "")
        obj = p.find("object")
        if m and obj is not None:
            out[int(m.group(1))] = obj
    return out


def _coords(panel: ET.Element, path: str, n_frames: int) -> np.ndarray:
    """(n_frames, 6) per frame: x0, y0, angle (rad), sx, sy, defined (1/0)."""
    cs = _get(panel, "coords", path)
    out = np.zeros((n_frames, 6))
    out[:, 3:6] = 1.0
    if cs is None:
        out[:, 5] = 0.0
        return out
    fixed = [_get(cs, k, path) for k in ("fixedorigin", "fixedangle", "fixedscale")]
    data = {k: v for k, v in _indexed(_props(cs).get("framedata")).items()
            if v.find("property") is not None}  # an empty entry is not a key frame
    if 0 not in data:
        raise InputError(path, "the coordinate system has no frame 0 entry",
                         place="coords/framedata")
    keys = sorted(data)
    values = {}
    for k in keys:
        row = []
        for name in ("xorigin", "yorigin", "angle", "xscale", "yscale"):
            v = _get(data[k], name, path, f"coords/framedata[{k}]/")
            if v is None or not math.isfinite(v):
                raise InputError(path, f"missing or bad {name}", place=f"coords/framedata[{k}]")
            row.append(v)
        if row[3] == 0 or row[4] == 0:
            raise InputError(path, "scale 0 px per unit", place=f"coords/framedata[{k}]")
        values[k] = row
    for part, cols in enumerate(((0, 1), (2,), (3, 4))):
        for c in cols:
            if fixed[part] is not False:  # fixed (the default): frame 0's value everywhere
                out[:, c] = values[0][c]
            else:
                for k in keys:            # each key frame's value until the next
                    if k < n_frames:
                        out[k:, c] = values[k][c]
    out[:, 2] = np.deg2rad(out[:, 2])
    return out


def image_to_world(xy_px: np.ndarray, cs: np.ndarray) -> np.ndarray:
    """World (X, Y) of image points (F, M, 2) under per-frame coordinate systems (F, 6)."""
    x0, y0, a, sx, sy = (cs[:, k, None] for k in range(5))
    u = (xy_px[..., 0] - x0) / sx
    w = -(xy_px[..., 1] - y0) / sy
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * u + s * w, -s * u + c * w], axis=-1)


_DECLARED = re.compile(rb"""^\s*<\?xml[^>]*?encoding\s*=\s*["']([A-Za-z0-9._-]+)["']""")


def _xml_root(data: str | bytes, path: str) -> tuple[ET.Element, str | None]:
    """The XML's root, and a note when it was read in another encoding than it declares.

    Tracker 5.1.3 wrote Latin-1 bytes (an author's "Jalón") under `encoding="UTF-8"`
    (its own example car-clip-22-JS.trz): where the bytes break the declared encoding,
    they are read as cp1252 (Windows' Latin-1), else Latin-1."""
    try:
        return ET.fromstring(data), None
    except ET.ParseError as exc:
        first, why = exc, str(exc)
    if isinstance(data, bytes):
        m = _DECLARED.match(data)
        declared = m.group(1).decode() if m else "UTF-8"
        try:
            data.decode(declared)
            broken = False
        except (UnicodeDecodeError, LookupError):
            broken = True
        for enc in ("cp1252", "latin-1") if broken else ():
            try:
                text = data.decode(enc)
            except UnicodeDecodeError:
                continue
            if m:  # the declaration would make the parser re-read the text in it
                text = text[:m.start(1)] + "utf-8" + text[m.end(1):]
            note = (f"read as {'Latin-1' if enc == 'latin-1' else enc}: the bytes are not "
                    f"the {declared} its XML declares")
            try:
                return ET.fromstring(text.encode("utf-8")), note
            except ET.ParseError as exc:  # broken in any encoding: say where, read so
                first, why = exc, f"{exc} ({note})"
                break
    line = first.position[0] if getattr(first, "position", None) else None
    raise InputError(path, f"malformed Tracker XML: {why}", line=line) from None


def _parse_trk(text: str | bytes, path: str, length_unit: str | None) -> Tracks:
    root, note = _xml_root(text, path)
    if root.tag != "object" or root.get("class") != _PANEL:
        raise InputError(path, f"not a Tracker file: the root is not a {_PANEL}")
    tracks = _props(root).get("tracks")
    names, points = [], []
    for item in (tracks.findall("property") if tracks is not None else []):
        obj = item.find("object")
        if obj is None or obj.get("class") != _POINT_MASS:
            continue
        name = _get(obj, "name", path) or f"mass{len(names) + 1}"
        if name in names:
            raise InputError(path, f"two point tracks are named {name!r}", place="tracks")
        pts = {}
        for k, fd in _indexed(_props(obj).get("framedata")).items():
            x, y = (_get(fd, c, path, f"{name}/framedata[{k}]/") for c in ("x", "y"))
            if x is None or y is None:
                continue
            pts[k] = (x, y)
        names.append(name)
        points.append(pts)
    if not names or not any(points):
        raise InputError(path, "no point track (PointMass) with marked frames in the Tracker file",
                         place="tracks")
    frames = np.array(sorted(set().union(*[p.keys() for p in points])), dtype=np.int64)
    xy_px = np.full((frames.size, len(names), 2), np.nan)
    where = {f: i for i, f in enumerate(frames.tolist())}
    for j, pts in enumerate(points):
        for k, v in pts.items():
            xy_px[where[k], j] = v
    cs = _coords(root, path, int(frames[-1]) + 1)[frames]
    meta = {"source_note": note} if note else {}
    unit = length_unit or _get(root, "length_unit", path)
    xy_mm = None
    if cs[:, 5].all() and unit:
        factor = length_factor(unit, path, "length_unit" if not length_unit else "--length-unit")
        xy_mm = image_to_world(xy_px, cs) * factor
        meta["world_unit"] = unit
    # time: starttime + (frame - startframe) * delta_t, ms
    clip = _get(root, "videoclip", path)
    control = _get(root, "clipcontrol", path)
    video = _get(clip, "video", path) if clip is not None else None
    dt = _get(control, "delta_t", path) or _get(video, "delta_t", path)
    t = None
    if dt is not None and math.isfinite(dt) and dt > 0:
        start = _get(clip, "startframe", path) or 0
        t0 = _get(clip, "starttime", path)
        t0 = t0 if t0 is not None and math.isfinite(t0) else 0.0
        t = (t0 + (frames - start) * dt) / 1000.0
    w, h = _get(root, "width", path), _get(root, "height", path)
    size = (int(w), int(h)) if w and h else None
    return Tracks("tracker", path, tuple(names), frames, t=t, xy_mm=xy_mm, xy_px=xy_px,
                  image_size=size, meta=meta)


def read_trk(path: str, length_unit: str | None = None) -> Tracks:
    """Point tracks of a Tracker .trk file: pixels and world mm (coordinate system applied)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
    return _parse_trk(data, path, length_unit)


def read_trz(path: str, length_unit: str | None = None) -> Tracks:
    """The .trk inside a Tracker .trz (zip) file."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = [n for n in zf.namelist() if n.lower().endswith(".trk")]
            if not names:
                raise InputError(path, "the .trz (zip) holds no .trk file")
            if len(names) > 1:
                raise InputError(path, f"the .trz holds {len(names)} .trk files "
                                       f"({', '.join(names)}): unzip the one to read")
            data = zf.read(names[0])
    except zipfile.BadZipFile as exc:
        raise InputError(path, f"not a readable zip file: {exc}") from None
    tracks = _parse_trk(data, f"{path}!{names[0]}", length_unit)
    return tracks.with_(path=path, meta={**tracks.meta, "trk": names[0]})


# -- Export Data text ---------------------------------------------------------------------------

def _split(line: str, delim: str | None) -> list[str]:
    return line.split() if delim is None else [c.strip() for c in line.rstrip("\r\n").split(delim)]


def _delimiter(header: str) -> str | None:
    for d in ("\t", ";", ","):
        if d in header:
            return d
    return None  # runs of spaces


def read_tracker_text(path: str, length_unit: str | None = None) -> Tracks:
    """Tracker's "Export Data" text: t in s and x, y in the (unwritten) world unit per track."""
    lines = read_text(path).splitlines()
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    if len(numbered) < 3:
        raise InputError(path, "too short for Tracker's exported data (name, columns, rows)")
    k = 1 if numbered[0][1].strip().lower().startswith("#multi") else 0
    (_, names_line), (head_no, head_line) = numbered[k], numbered[k + 1]
    delim = _delimiter(head_line)
    header = _split(head_line, delim)
    if not header or header[0] != "t":
        raise InputError(path, f"the column names must start with t, got {header[:1]}",
                         line=head_no)
    cells = _split(names_line, delim)
    multi = bool(k) or len([c for c in cells if c]) > 1  # names over their columns
    if not multi:
        cells = [names_line.strip()]
    owner, current = [], None
    for j in range(len(header)):
        if multi and j < len(cells) and cells[j]:
            current = cells[j]
        owner.append(current if multi else cells[0])
    groups: dict[str, dict[str, int]] = {}
    for j, name in enumerate(header[1:], 1):
        if owner[j] is None:
            continue
        groups.setdefault(owner[j], {}).setdefault(name, j)
    groups = {g: c for g, c in groups.items() if ("x" in c and "y" in c)
              or ("pixelx" in c and "pixely" in c)}
    if not groups:
        raise InputError(path, "no track with x and y columns", line=head_no)
    rows, row_lines = [], []
    for no, ln in numbered[k + 2:]:
        rows.append(_split(ln, delim))
        row_lines.append(no)
    decimal_comma = delim != "," and any("," in c for r in rows[:50] for c in r)

    def col(j, what):
        out = np.empty(len(rows))
        for i, r in enumerate(rows):
            try:
                out[i] = number(r[j] if j < len(r) else "", decimal_comma)
            except ValueError:
                raise InputError(path, f"column {what}: {r[j]!r} is not a number",
                                 line=row_lines[i]) from None
        return out

    t = col(0, "t")
    keep = np.isfinite(t)
    names = list(groups)
    f = int(keep.sum())
    factor = length_factor(length_unit, path, "--length-unit") if length_unit else None
    xy_mm = np.full((f, len(names), 2), np.nan) if factor else None
    has_px = all("pixelx" in c for c in groups.values())
    xy_px = np.full((f, len(names), 2), np.nan) if has_px else None
    for m, name in enumerate(names):
        c = groups[name]
        if xy_mm is not None:
            xy_mm[:, m, 0] = col(c["x"], f"{name} x")[keep] * factor
            xy_mm[:, m, 1] = col(c["y"], f"{name} y")[keep] * factor
        if xy_px is not None:
            xy_px[:, m, 0] = col(c["pixelx"], f"{name} pixelx")[keep]
            xy_px[:, m, 1] = col(c["pixely"], f"{name} pixely")[keep]
    if xy_mm is None and xy_px is None:
        raise InputError(path, "Tracker's exported text does not say its length unit: give "
                               "--length-unit (m, cm, mm, ...)", line=head_no)
    return Tracks("tracker-text", path, tuple(names),
                  np.arange(f), t=t[keep], xy_mm=xy_mm, xy_px=xy_px,
                  meta={"world_unit": length_unit} if length_unit else {})


def looks_like_tracker_text(lines: list[str]) -> bool:
    """The first lines of Tracker's exported data: `#multi:` or a name, then `t` and x, y."""
    body = [ln for ln in lines if ln.strip()]
    if len(body) < 2:
        return False
    k = 1 if body[0].strip().lower().startswith("#multi") else 0
    if len(body) < k + 2:
        return False
    head = _split(body[k + 1], _delimiter(body[k + 1]))
    return bool(head) and head[0] == "t" and "x" in head and "y" in head


def is_tracker_xml(head: bytes) -> bool:
    return _PANEL.encode() in head



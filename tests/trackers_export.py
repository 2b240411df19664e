"""Writers of other trackers' formats, for tests: a simulated recording exported as each
program documents its files (../shared/data/real/trackers/README.md and the programs'
sources), written independently of fitlug's readers.

Pixels: ground mm (x, y up) -> image px with a scale S and image height H, origin top-left,
y down: x_px = x / S, y_px = H - y / S (the mapping of `fit-lug track`'s scale).
"""

import csv
import io
import math
import zipfile

import numpy as np

S, H = 0.05, 1000.0  # mm per px, image height px


def table(rec):
    """(t (F,), names, xy (F, M, 2) mm) of a Recording, NaN where missing."""
    t = np.unique(rec.t)
    xy = np.full((t.size, rec.n_markers, 2), np.nan)
    row = np.searchsorted(t, rec.t)
    xy[row, rec.marker_index, 0], xy[row, rec.marker_index, 1] = rec.x, rec.y
    return t, list(rec.markers), xy


def to_px(xy):
    return np.stack([xy[..., 0] / S, H - xy[..., 1] / S], axis=-1)


def tracker_trk(rec, angle_deg=3.0, origin=(400.0, 700.0), px_per_m=20000.0) -> str:
    """OSP Tracker 5 XML: PointMass framedata in image px; a coordinate system (degrees,
    px per metre) whose world frame is the ground frame in metres. World -> image by OSP's
    ImageCoordSystem.updateTransforms: x = s cos X - s sin Y + x0, y = -s sin X - s cos Y + y0."""
    t, names, xy = table(rec)
    a = math.radians(angle_deg)
    X, Y = xy[..., 0] / 1000, xy[..., 1] / 1000
    px = np.stack([px_per_m * (math.cos(a) * X - math.sin(a) * Y) + origin[0],
                   px_per_m * (-math.sin(a) * X - math.cos(a) * Y) + origin[1]], axis=-1)
    dt = 1000 * float(np.median(np.diff(t)))
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<object class="org.opensourcephysics.cabrillo.tracker.TrackerPanel">',
           '    <property name="width" type="double">1920.0</property>',
           '    <property name="height" type="double">1080.0</property>',
           '    <property name="videoclip" type="object">',
           '    <object class="org.opensourcephysics.media.core.VideoClip">',
           '        <property name="startframe" type="int">0</property>',
           '        <property name="stepsize" type="int">1</property>',
           '        <property name="starttime" type="double">0.0</property>',
           '    </object>', '    </property>',
           '    <property name="clipcontrol" type="object">',
           '    <object class="org.opensourcephysics.media.core.StepperClipControl">',
           f'        <property name="delta_t" type="double">{dt!r}</property>',
           '    </object>', '    </property>',
           '    <property name="coords" type="object">',
           '    <object class="org.opensourcephysics.media.core.ImageCoordSystem">',
           '        <property name="fixedorigin" type="boolean">true</property>',
           '        <property name="fixedangle" type="boolean">true</property>',
           '        <property name="fixedscale" type="boolean">true</property>',
           '        <property name="framedata" type="array" class="[Lorg.opensourcephysics.media.core.ImageCoordSystem$FrameData;">',
           '            <property name="[0]" type="object">',
           '            <object class="org.opensourcephysics.media.core.ImageCoordSystem$FrameData">',
           f'                <property name="xorigin" type="double">{origin[0]!r}</property>',
           f'                <property name="yorigin" type="double">{origin[1]!r}</property>',
           f'                <property name="angle" type="double">{angle_deg!r}</property>',
           f'                <property name="xscale" type="double">{px_per_m!r}</property>',
           f'                <property name="yscale" type="double">{px_per_m!r}</property>',
           '            </object>', '            </property>', '        </property>',
           '    </object>', '    </property>',
           '    <property name="length_unit" type="string">m</property>',
           '    <property name="tracks" type="collection" class="java.util.ArrayList">']
    for m, name in enumerate(names):
        out += ['        <property name="item" type="object">',
                '        <object class="org.opensourcephysics.cabrillo.tracker.PointMass">',
                f'            <property name="name" type="string">{name}</property>',
                '            <property name="framedata" type="array" class="[Lorg.opensourcephysics.cabrillo.tracker.PointMass$FrameData;">']
        for k in range(t.size):
            if np.isfinite(px[k, m, 0]):
                out += [f'                <property name="[{k}]" type="object">',
                        '                <object class="org.opensourcephysics.cabrillo.tracker.PointMass$FrameData">',
                        f'                    <property name="x" type="double">{float(px[k, m, 0])!r}</property>',
                        f'                    <property name="y" type="double">{float(px[k, m, 1])!r}</property>',
                        '                </object>', '                </property>']
        out += ['            </property>', '        </object>', '        </property>']
    out += ['    </property>', '</object>', '']
    return "\n".join(out)


def tracker_trz(rec, path):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("run_thumbnail.png", b"")
        zf.writestr("run.trk", tracker_trk(rec))


def tracker_text(rec) -> str:
    """Tracker's Export Data of several tracks: `#multi:`, the names over their columns,
    `t` and x, y per track (metres), tab-delimited, decimal comma (a German locale)."""
    t, names, xy = table(rec)
    lines = ["#multi:", "\t" + "".join(n + "\t\t" for n in names).rstrip("\t"),
             "t\t" + "\t".join("x\ty" for _ in names)]
    fmt = lambda v: "" if not np.isfinite(v) else f"{v:.9E}".replace(".", ",")  # noqa: E731
    for k in range(t.size):
        cells = [fmt(t[k])] + [fmt(xy[k, m, a] / 1000) for m in range(len(names)) for a in (0, 1)]
        lines.append("\t".join(cells))
    return "\n".join(lines) + "\n"


def dltdv(rec, style="UV") -> str:
    """DLTdv xypts.csv, one camera: U/V (8.4+, top-left) or X/Y written by DLTdv7
    (bottom-left origin, y up); `%.6f`, NaN where missing; no frame or time column."""
    _, names, xy = table(rec)
    px = to_px(xy)
    if style == "XY7":
        px[..., 1] = H - px[..., 1]
        head = [f"pt{m + 1}_cam1_{a}" for m in range(len(names)) for a in "XY"]
    else:
        head = [f"{n}_cam1_{a}" for n in names for a in "UV"]
    rows = [",".join(head)]
    for k in range(px.shape[0]):
        rows.append(",".join("NaN" if not np.isfinite(v) else f"{v:.6f}" for v in px[k].ravel()))
    return "\n".join(rows) + "\n"


def kinovea_csv(rec) -> str:
    """Kinovea trajectory CSV in a decimal-comma locale: ';' list separator, every cell
    quoted, time in s, uncalibrated (pixels in Kinovea's coordinate system, y up) float32."""
    t, names, xy = table(rec)
    px = to_px(xy)
    px[..., 1] = H - px[..., 1]  # y up
    cell = lambda v: "" if not np.isfinite(v) else f'"{np.float32(v)}"'.replace(".", ",")  # noqa
    lines = [";".join(['"Time"'] + [f'"{n}/0/{a}"' for n in names for a in "XY"])]
    for k in range(t.size):
        lines.append(";".join([cell(t[k])] + [cell(v) for v in px[k].ravel()]))
    return "\n".join(lines) + "\n"


def kinovea_txt(rec) -> str:
    """Kinovea trajectory TXT of an older version: time codes h:mm:ss:cc, values in cm."""
    t, names, xy = table(rec)
    lines = ["#Kinovea Trajectory data export", "#T X Y", ""]
    for m, n in enumerate(names):
        lines.append(f"# {n}")
        for k in range(t.size):
            if np.isfinite(xy[k, m, 0]):
                cs = int(round(t[k] * 100))
                code = f"{cs // 360000}:{cs // 6000 % 60:02d}:{cs // 100 % 60:02d}:{cs % 100:02d}"
                lines.append(f"{code} {xy[k, m, 0] / 10:.7f} {xy[k, m, 1] / 10:.7f}".replace(".", ","))
        lines.append("")
    return "\n".join(lines)


def dlc_csv(rec, individuals=False) -> str:
    """DeepLabCut CSV: scorer, [individuals,] bodyparts, coords rows; index = frame from 0;
    pixels y down; likelihood 0.95 (kept at any threshold below)."""
    _, names, xy = table(rec)
    px = to_px(xy)
    scorer = "DLC_resnet50_testNov1shuffle1_1000"
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["scorer"] + [scorer] * 3 * len(names))
    if individuals:
        w.writerow(["individuals"] + ["robot"] * 3 * len(names))
    w.writerow(["bodyparts"] + [n for n in names for _ in range(3)])
    w.writerow(["coords"] + ["x", "y", "likelihood"] * len(names))
    for k in range(px.shape[0]):
        cells = []
        for m in range(len(names)):
            ok = np.isfinite(px[k, m, 0])
            cells += [repr(float(px[k, m, 0])) if ok else "", repr(float(px[k, m, 1])) if ok else "",
                      "0.95" if ok else ""]
        w.writerow([k] + cells)
    return out.getvalue()


def dlc_dataframe(rec):
    import pandas as pd

    _, names, xy = table(rec)
    px = to_px(xy)
    cols = pd.MultiIndex.from_tuples([("DLC_scorer", n, c) for n in names
                                      for c in ("x", "y", "likelihood")],
                                     names=["scorer", "bodyparts", "coords"])
    data = np.concatenate([px, np.full(px.shape[:2] + (1,), 0.95)], axis=-1)
    return pd.DataFrame(data.reshape(px.shape[0], -1), columns=cols)


def trackpy_rows(rec, ids):
    """trackpy's linked table: y, x, mass, ..., frame, particle; absent rows where missing."""
    _, names, xy = table(rec)
    px = to_px(xy)
    rows = []
    for k in range(px.shape[0]):
        for m in range(len(names)):
            if np.isfinite(px[k, m, 0]):
                rows.append((px[k, m, 1], px[k, m, 0], 1234.5, 2.1, 0.05, 40.0, 5000.0, 0.01,
                             k, ids[m]))
    return ["y", "x", "mass", "size", "ecc", "signal", "raw_mass", "ep", "frame", "particle"], rows


def trackpy_csv(rec, ids) -> str:
    head, rows = trackpy_rows(rec, ids)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([""] + head)  # pandas' to_csv writes the index first, unnamed
    for i, r in enumerate(rows):
        w.writerow([i, *[repr(float(v)) for v in r[:8]], r[8], r[9]])
    return out.getvalue()

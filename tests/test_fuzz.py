"""Fuzzing the parsers: seeded mutations of real inputs get a result or fitlug.InputError.

Every case is one seed: a valid input (the bundled recording, in long and in wide form, the
bundled rig.toml, a calib.json, a .cine header) goes through one to three random
mutations (truncated lines, swapped / deleted / duplicated fields, columns and rows,
huge, NaN, infinite, negative and malformed numbers, binary garbage, other encodings,
line endings and separators) and is parsed only (nothing is fitted). Any exception other
than InputError is a defect; the failure message names the seed and the mutations, so
`case(kind, seed)` rebuilds the input. `benchmarks/bench_fuzz.py` runs the same cases by
the ten thousand.
"""

from __future__ import annotations

import json
import os
import random
import warnings

import pytest

from fitlug._errors import InputError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REF_CSV = os.path.join(ROOT, "data", "reference", "trajectories.csv")
REF_RIG = os.path.join(ROOT, "data", "reference", "rig.toml")
import shared_data  # noqa: E402 - tests/ is on sys.path (conftest)

CINE_DIR = os.path.join(shared_data.REAL, "cine")
CINE_BASES = ("phantom_v1610.cine", "packed_12bpp.cine", "cine_legacy.cine")

# numbers and non-numbers a field may become
SPECIAL = ["", " ", "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e19", "-1e19",
           "9223372036854775807", "9223372036854775808", "-9223372036854775809",
           "1" + "0" * 400, "1e308", "1e309", "-1e400", "1e-320", "5e-324", "0", "-0", "-1",
           "-1e300", "1e300", "1e5", "649", "0.5", "1.5", "1_000", "0x10", "1,5", "1.2.3",
           "abc", "lug", "body", "wheel", "\x00", '"', '"a,b"', "∞", "١٢", "１２", "\ufeff1",
           "1e", "e5", "+", "-", ".", "..", "#", "# fps: 0", "\t", "None", "null", "true",
           "[1, 2]", "{}", "'1'"]
SEPARATORS = [";", "\t", " ", "|", ", ", ",,"]
ENCODINGS = ["utf-16", "utf-16-le", "utf-32", "latin-1", "cp1252", "utf-8-sig"]


# -- base inputs -------------------------------------------------------------------------

def _lines(path):
    with open(path, encoding="utf-8") as fh:
        return fh.read().splitlines()


def base_long(rows: int = 240) -> str:
    """The bundled recording's metadata, header and first `rows` rows (20 frames)."""
    lines = _lines(REF_CSV)
    n_meta = sum(1 for line in lines if line.startswith("#"))
    return "\n".join(lines[:n_meta + 1 + rows]) + "\n"


def base_wide(text: str) -> str:
    """The same samples in wide form: time_s, frame, <ID>_x_mm, <ID>_y_mm, ..."""
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    col = {name: j for j, name in enumerate(header)}
    markers, frames = [], {}
    for r in rows:
        m = r[col["marker"]]
        if m not in markers:
            markers.append(m)
        frames.setdefault((r[col["time_s"]], r[col["frame"]]), {})[m] = (r[col["x_mm"]],
                                                                          r[col["y_mm"]])
    out = ["# fps: 100", ",".join(["time_s", "frame"] + [f"{m}_{a}_mm" for m in markers
                                                        for a in "xy"])]
    for (t, f), xy in frames.items():
        out.append(",".join([t, f] + [v for m in markers for v in xy.get(m, ("", ""))]))
    return "\n".join(out) + "\n"


def base_calib() -> str:
    return json.dumps({
        "format": "fitlug-calibration", "version": 1,
        "camera_matrix": [[2000.0, 0.0, 319.5], [0.0, 2000.0, 239.5], [0.0, 0.0, 1.0]],
        "dist_coeffs": [-0.02, 0.0, 0.0, 0.0, 0.0], "image_size": [640, 480], "rms_px": 0.1,
        "per_view": [{"image": "a.png", "rms_px": 0.1, "outlier": False}], "mm_per_px": 0.39,
        "board": None, "flags": 0, "flag_names": [], "std_px": None, "rejected": [],
        "scale": {"method": "points", "p1_px": [1, 2], "p2_px": [3, 4], "distance_mm": 5.0},
    }, indent=2)


# -- mutations ---------------------------------------------------------------------------

def _field(rng: random.Random) -> str:
    r = rng.random()
    if r < 0.7:
        return rng.choice(SPECIAL)
    if r < 0.85:
        return repr(rng.uniform(-1e6, 1e6) * 10 ** rng.randint(-30, 30))
    return "".join(chr(rng.randint(1, 0x2FF)) for _ in range(rng.randint(1, 6)))


def _text_ops(rng: random.Random, text: str, sep: str = ",") -> tuple[str, str]:
    """One mutation of CSV/TOML text; returns (text, name of the mutation)."""
    lines = text.split("\n")
    i = rng.randrange(len(lines))
    op = rng.choice(["truncate", "truncate_line", "delete_line", "duplicate_line", "swap_lines",
                     "shuffle_lines", "field", "field", "field", "swap_fields", "delete_field",
                     "duplicate_field", "delete_column", "duplicate_column", "swap_columns",
                     "garbage", "flip_bytes", "separator", "line_endings", "blank_lines",
                     "header", "scale",
                     # issue 30 item 5: a trailer line, one absurd value, time jitter
                     "trailer", "absurd", "jitter"])
    fields = lines[i].split(sep)
    j = rng.randrange(len(fields))
    if op == "truncate":
        text = text[:rng.randrange(len(text) + 1)]
    elif op == "truncate_line":
        lines[i] = lines[i][:rng.randrange(len(lines[i]) + 1)]
        text = "\n".join(lines)
    elif op == "delete_line":
        del lines[i]
        text = "\n".join(lines)
    elif op == "duplicate_line":
        lines.insert(rng.randrange(len(lines) + 1), lines[i])
        text = "\n".join(lines)
    elif op == "swap_lines":
        k = rng.randrange(len(lines))
        lines[i], lines[k] = lines[k], lines[i]
        text = "\n".join(lines)
    elif op == "shuffle_lines":
        body = lines[1:]
        rng.shuffle(body)
        text = "\n".join(lines[:1] + body)
    elif op == "field":
        for _ in range(rng.choice([1, 1, 1, 3, 20])):
            i = rng.randrange(len(lines))
            fields = lines[i].split(sep)
            fields[rng.randrange(len(fields))] = _field(rng)
            lines[i] = sep.join(fields)
        text = "\n".join(lines)
    elif op == "swap_fields":
        k = rng.randrange(len(fields))
        fields[j], fields[k] = fields[k], fields[j]
        lines[i] = sep.join(fields)
        text = "\n".join(lines)
    elif op == "delete_field":
        del fields[j]
        lines[i] = sep.join(fields)
        text = "\n".join(lines)
    elif op == "duplicate_field":
        fields.insert(j, fields[j])
        lines[i] = sep.join(fields)
        text = "\n".join(lines)
    elif op in ("delete_column", "duplicate_column", "swap_columns"):
        k = rng.randrange(8)
        m = rng.randrange(8)
        out = []
        for line in lines:
            if line.startswith("#"):
                out.append(line)
                continue
            f = line.split(sep)
            if k < len(f):
                if op == "delete_column":
                    del f[k]
                elif op == "duplicate_column":
                    f.insert(k, f[k])
                elif m < len(f):
                    f[k], f[m] = f[m], f[k]
            out.append(sep.join(f))
        text = "\n".join(out)
    elif op == "garbage":
        pos = rng.randrange(len(text) + 1)
        junk = "".join(chr(rng.randrange(0, 256)) for _ in range(rng.randint(1, 64)))
        text = text[:pos] + junk + text[pos:]
    elif op == "flip_bytes":
        chars = list(text)
        for _ in range(rng.randint(1, 10)):
            if chars:
                chars[rng.randrange(len(chars))] = chr(rng.randrange(0, 0x110000) if
                                                       rng.random() < 0.1 else rng.randrange(128))
        text = "".join(c for c in chars if not 0xD800 <= ord(c) <= 0xDFFF)
    elif op == "separator":
        text = text.replace(sep, rng.choice(SEPARATORS))
    elif op == "line_endings":
        text = text.replace("\n", rng.choice(["\r\n", "\r", "\n\n", "\x0b", "\u2028"]))
    elif op == "blank_lines":
        lines.insert(i, rng.choice(["", " ", "#", "# fps: 50", "# fps: nan", "#x: y", ",,,"]))
        text = "\n".join(lines)
    elif op == "header":
        first = next((n for n, line in enumerate(lines) if not line.startswith("#")), 0)
        f = lines[first].split(sep)
        f[rng.randrange(len(f))] = rng.choice(["time_s", "marker", "role", "x_mm", "y_mm",
                                               "frame", "sigma_mm", "TIME_S", "", "C1_x_mm",
                                               "B01_y_mm", "x", "quality", _field(rng)])
        lines[first] = sep.join(f)
        text = "\n".join(lines)
    elif op == "scale":  # a whole column in another unit
        k = rng.randrange(8)
        factor = rng.choice([1e-3, 1e3, 1e6, -1.0, 1e300])
        out = []
        for line in lines:
            f = line.split(sep)
            try:
                f[k] = repr(float(f[k]) * factor)
            except (IndexError, ValueError):
                pass
            out.append(sep.join(f))
        text = "\n".join(out)
    elif op == "trailer":  # a line that is no data, at the end or among the rows
        lines.insert(rng.choice([len(lines), i]),
                     rng.choice(["Total rows: 7800", "end of data", "---", "Σ 12 markers"]))
        text = "\n".join(lines)
    elif op == "absurd":  # one number far out of range
        fields[j] = rng.choice(["1e300", "-1e300", "1e308", "4e7", "1e-320"])
        lines[i] = sep.join(fields)
        text = "\n".join(lines)
    elif op == "jitter":  # a clock's jitter on the first column (time_s)
        out = []
        for line in lines:
            f = line.split(sep)
            try:
                f[0] = repr(float(f[0]) + rng.uniform(-0.002, 0.002))
            except ValueError:
                pass
            out.append(sep.join(f))
        text = "\n".join(out)
    return text, op


def _encode(rng: random.Random, text: str) -> tuple[bytes, str]:
    r = rng.random()
    if r < 0.02:  # a BOM (Windows editors), or the file gzip-compressed
        import gzip

        raw = text.encode("utf-8", errors="surrogatepass")
        return ((b"\xef\xbb\xbf" + raw, "bom") if r < 0.01
                else (gzip.compress(raw, mtime=0), "gzip"))
    if rng.random() < 0.06:
        encoding = rng.choice(ENCODINGS)
        return text.encode(encoding, errors="replace"), f"encode:{encoding}"
    return text.encode("utf-8", errors="surrogatepass"), ""


def mutate_text(rng: random.Random, text: str, sep: str = ",") -> tuple[bytes, list[str]]:
    ops = []
    for _ in range(rng.choice([1, 1, 2, 3])):
        text, op = _text_ops(rng, text, sep)
        ops.append(op)
    data, enc = _encode(rng, text)
    return data, ops + ([enc] if enc else [])


def _json_values(rng: random.Random):
    return rng.choice([None, True, False, 0, -1, 1e400, -1e400, float("nan"), 10 ** 400,
                       1e-320, "x", "", [], {}, [1, 2], [[1, 2, 3]] * 3, [[1, 2, 3]] * 2,
                       [0.0] * 5, [0.0] * 7, [640.5, 480], [-640, 480], [0, 0], {"a": 1},
                       "NaN", [[2000.0, 0.0, 1.0], [0.0, -5.0, 1.0], [0.0, 0.0, 1.0]],
                       [["a", 0, 1]] * 3, 1e19, -1e19, [1e400, 1]])


def mutate_json(rng: random.Random, text: str) -> tuple[bytes, list[str]]:
    ops = []
    if rng.random() < 0.5:  # structural mutations of the parsed object
        data = json.loads(text)
        for _ in range(rng.choice([1, 1, 2, 3])):
            key = rng.choice(list(data) or ["x"])
            op = rng.choice(["value", "value", "delete", "nest", "rename", "top"])
            if op == "value":
                data[key] = _json_values(rng)
            elif op == "delete":
                data.pop(key, None)
            elif op == "nest":
                depth = rng.choice([2, 50, 5000])
                data[key] = json.loads("[" * depth + "1" + "]" * depth) if depth < 900 \
                    else "[" * depth
            elif op == "rename":
                data[key + rng.choice(["_", "s", ""])] = data.pop(key, None)
            else:
                data = _json_values(rng)
                ops.append("top")
                break
            ops.append(f"{op}:{key}")
        try:
            text = json.dumps(data)
        except (ValueError, TypeError, RecursionError):
            text = "[" * 100000
            ops.append("deep")
        if not isinstance(data, dict):
            return text.encode(), ops
        return text.encode("utf-8", errors="surrogatepass"), ops
    data, more = mutate_text(rng, text)
    return data, ops + more


def mutate_binary(rng: random.Random, data: bytes, header: int = 4096) -> tuple[bytes, list[str]]:
    """Mutations of a binary file, aimed at its first `header` bytes (the .cine headers)."""
    buf = bytearray(data)
    ops = []
    for _ in range(rng.choice([1, 1, 2, 3, 6])):
        op = rng.choice(["byte", "byte", "u16", "u32", "u32", "u64", "zero", "truncate",
                         "garbage", "copy"])
        pos = rng.randrange(min(header, len(buf)) or 1)
        if op == "byte" and buf:
            buf[pos % len(buf)] = rng.randrange(256)
        elif op in ("u16", "u32", "u64"):
            n = {"u16": 2, "u32": 4, "u64": 8}[op]
            pos -= pos % 2
            value = rng.choice([0, 1, 2, 3, 7, 8, 10, 12, 16, 24, 255, 256, 0x7FFF, 0xFFFF,
                                0x7FFFFFFF, 0xFFFFFFFF, 2 ** 63, 2 ** 64 - 1,
                                rng.randrange(2 ** (8 * n))]) % 2 ** (8 * n)
            buf[pos:pos + n] = value.to_bytes(n, "little")
        elif op == "zero":
            buf[pos:pos + rng.randint(1, 256)] = bytes(min(256, len(buf) - pos))
        elif op == "truncate":
            del buf[rng.choice([rng.randrange(len(buf) + 1), rng.randrange(header)]):]
        elif op == "garbage":
            buf[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
        elif op == "copy" and buf:
            src = rng.randrange(len(buf))
            buf[pos:pos + 64] = buf[src:src + 64]
        ops.append(op)
    return bytes(buf), ops


# -- cases -------------------------------------------------------------------------------

_BASES: dict = {}


def _base(kind: str):
    if kind not in _BASES:
        if kind == "trajectories":
            long = base_long()
            _BASES[kind] = (long, base_wide(long))
        elif kind == "rig":
            with open(REF_RIG, encoding="utf-8") as fh:
                _BASES[kind] = fh.read() + '\n[markers]\nbody = ["C1", "C2"]\n'
        elif kind == "calib":
            _BASES[kind] = base_calib()
        elif kind == "cine":
            bases = []
            for name in CINE_BASES:
                with open(os.path.join(CINE_DIR, name), "rb") as fh:
                    bases.append(fh.read())
            _BASES[kind] = bases
    return _BASES[kind]


def case(kind: str, seed: int) -> tuple[bytes, list[str], dict]:
    """The input of case `seed` of parser `kind`: (bytes, mutations, extra arguments)."""
    rng = random.Random(f"{kind}:{seed}")
    extra: dict = {}
    if kind == "trajectories":
        long, wide = _base(kind)
        base = wide if rng.random() < 0.25 else long
        data, ops = mutate_text(rng, base)
        if rng.random() < 0.2:
            extra["rig_fps"] = rng.choice([100.0, 50.0, 1e-3, 99.0])
        return data, (["wide"] if base is wide else []) + ops, extra
    if kind == "rig":
        return mutate_text(rng, _base(kind), sep=rng.choice([" = ", "=", ", ", "."])) + (extra,)
    if kind == "calib":
        return mutate_json(rng, _base(kind)) + (extra,)
    if kind == "cine":
        bases = _base(kind)
        k = rng.randrange(len(bases))
        data, ops = mutate_binary(rng, bases[k])
        return data, [CINE_BASES[k]] + ops, extra
    raise ValueError(kind)


def parse(kind: str, path: str, extra: dict) -> None:
    """Parse `path` as `kind` (nothing more: no fit)."""
    if kind == "trajectories":
        from fitlug.io import Rig, read_trajectories
        rig = Rig(fps=extra["rig_fps"]) if "rig_fps" in extra else None
        read_trajectories(path, rig=rig)
    elif kind == "rig":
        from fitlug.io import read_rig
        read_rig(path)
    elif kind == "calib":
        from fitlug.vision.calibrate._calib_io import load_calibration
        load_calibration(path)
    elif kind == "cine":
        from fitlug.vision.read._cine import CineFile
        with CineFile(path) as cine:
            if cine.n_frames:
                cine.read(0)  # the first frame too: the header decides where it lies
    else:
        raise ValueError(kind)


SUFFIX = {"trajectories": ".csv", "rig": ".toml", "calib": ".json", "cine": ".cine"}


def run_case(kind: str, seed: int, folder: str) -> tuple[str, str]:
    """('ok' | 'InputError' | the exception's type name, detail) of one case."""
    data, ops, extra = case(kind, seed)
    path = os.path.join(folder, f"fuzz_{os.getpid()}{SUFFIX[kind]}")
    with open(path, "wb") as fh:
        fh.write(data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            parse(kind, path, extra)
    except InputError as exc:
        if "\n" in str(exc):
            return "InputError on two lines", f"seed {seed} {ops}: {exc!s:.300}"
        return "InputError", ""
    except Exception as exc:  # noqa: BLE001 - the point: any other exception is a defect
        return type(exc).__name__, f"seed {seed} {ops}: {exc!s:.300}"
    return "ok", ""


# -- the tests (a few thousand cases, parse only) -----------------------------------------

@pytest.mark.parametrize("kind,n", [("trajectories", 1500), ("rig", 1200), ("calib", 600)])
def test_fuzzed_inputs_raise_only_input_error(tmp_path, kind, n):
    outcomes: dict[str, int] = {}
    defects = []
    for seed in range(n):
        outcome, detail = run_case(kind, seed, str(tmp_path))
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
        if detail:
            defects.append(f"{outcome}: {detail}")
    assert not defects, f"{len(defects)} of {n} cases: " + " | ".join(defects[:5])
    # the mutations must reach both sides: inputs still read and inputs refused
    assert outcomes.get("InputError", 0) > n // 4, outcomes
    assert outcomes.get("ok", 0) > n // 50, outcomes


@pytest.mark.skipif(not os.path.isdir(CINE_DIR), reason="real .cine data not present")
def test_fuzzed_cine_headers_raise_only_input_error(tmp_path):
    defects = [detail for seed in range(300)
               for outcome, detail in [run_case("cine", seed, str(tmp_path))] if detail]
    assert not defects, " | ".join(defects[:5])


def test_the_cases_are_reproducible():
    assert case("trajectories", 7) == case("trajectories", 7)
    assert case("rig", 3) != case("rig", 4)

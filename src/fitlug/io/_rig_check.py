"""Where the keys of rig.toml stand: a known key outside its table, or a near-miss of one.

A key in the wrong place is not read where it belongs, so the fit would silently use the
default in its stead (`lugs_in_contact = 6` above any `[track]` header, `lugs_in_contact`
under `[vehicle]`, `mass = 10` for `mass_kg`). Such keys are refused with one line naming
the file, the line, the key and where it belongs. Other unknown keys of the tables fitlug
reads ([track], [vehicle], [ground], [markers]) are kept in `Rig.extra` with a warning;
[camera], the top level and other tables stay free for the user's notes.
"""

from __future__ import annotations

import difflib
import re
import warnings

from .._errors import InputError

_UNIT = re.compile(r"_(mm|kg|n)$", re.IGNORECASE)
_WARN_TABLES = ("track", "vehicle", "ground", "markers")
# MODEL.md's symbols and plain words, written for the key they stand for
_ALIASES = {"l": "load_bearing_length_mm", "length": "load_bearing_length_mm",
            "n": "lugs_in_contact", "p": "lug_pitch_mm", "pitch": "lug_pitch_mm",
            "m": "mass_kg", "f_d": "drawbar_pull_N", "fd": "drawbar_pull_N",
            "pull": "drawbar_pull_N", "ground": "name"}


def _bare(key: str) -> str:
    """A key without its unit suffix, lower case: mass_kg -> mass."""
    return _UNIT.sub("", key.lower())


def _near(key: str, keys) -> str | None:
    """The known key `key` most likely misspells, or None."""
    alias = _ALIASES.get(key.lower())
    if alias in keys:
        return alias
    by_bare = {_bare(k): k for k in keys}
    if key.lower() in by_bare and key not in keys:  # mass for mass_kg, lug_pitch for ...
        return by_bare[key.lower()]
    lower = {k.lower(): k for k in keys}
    if key.lower() in lower and key not in keys:  # Mass_kg
        return lower[key.lower()]
    close = difflib.get_close_matches(key.lower(), list(lower), n=1, cutoff=0.8) \
        or difflib.get_close_matches(_bare(key), list(by_bare), n=1, cutoff=0.8)
    if not close:
        return None
    return lower.get(close[0]) or by_bare.get(close[0])


def check_keys(path: str, data: dict, known: dict, tables: tuple, key_line) -> None:
    """Refuse a known key outside its table and a near-miss of a known key; warn about
    other unknown keys of the tables fitlug reads.

    Args:
        path: the rig file (for the messages).
        data: the parsed TOML.
        known: {(table, key): ...} of the keys fitlug reads.
        tables: the tables fitlug reads.
        key_line: key_line(table or None, key) -> line number or None.

    Raises:
        InputError: naming the file, the line, the key and the table it belongs in.
    """
    home: dict[str, str] = {}
    for table, key in known:
        home.setdefault(key, table)
    all_keys = list(home)

    def where(table):
        return f"[{table}]" if table else "the top level (above any [table] header)"

    def refuse(table, key, problem):
        raise InputError(path, f"{where(table)}: key {key!r} {problem}",
                         line=key_line(table, key))

    entries = []
    for name, content in data.items():
        if isinstance(content, dict):
            entries.extend((name, key) for key in content)
        else:
            entries.append((None, name))
    for table, key in entries:
        if (table, key) in known:
            continue
        if table is None and key.lower() in tables:
            continue  # `track = ...` at the top level: checked as a table by read_rig
        if key in home:
            right = home[key]
            fix = (f"add the [{right}] header above it" if table is None
                   else f"move it there")
            refuse(table, key, f"belongs under [{right}]: it is not read here ({fix})")
        own = [k for t, k in known if t == table] if table in tables else all_keys
        close = _near(key, own)
        if close:
            right = home[close]
            there = "" if right == table else f" under [{right}]"
            refuse(table, key, f"is not a key fitlug reads: did you mean {close!r}{there}? "
                               f"(as it stands the default is used)")
        if table in _WARN_TABLES:
            warnings.warn(f"{path}:{key_line(table, key)}: [{table}] unknown key {key!r} "
                          f"(kept in Rig.extra, not used by the fit)", stacklevel=3)

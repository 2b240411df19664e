"""Numbers as people read them: digits set by the uncertainty, one convention everywhere.

The report, the terminal and the corner-plot titles all print through these helpers:

- ``pm(0.0771578, 2.06e-6)`` -> ``"0.0771578 ± 0.0000021"``: the standard error (1 σ) to two
  significant digits, the value rounded at the same decimal place;
- ``interval(lo, hi, std, 95)`` -> ``"95 %: 0.077154 … 0.077162"``: an interval always names
  its level, and is printed with enough digits that its ends differ;
- ``num(x)`` for a number without an error (4 significant digits, no exponent for
  everyday magnitudes), ``sig(x, n)`` for a chosen number of significant digits.

Very large or very small magnitudes share one power of ten:
``(3.740 ± 0.037) × 10⁻⁵``; ``ascii=True`` writes ``+/-``, ``...`` and ``e-5`` instead.
"""

from __future__ import annotations

import math

_SUP = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
PLAIN_EXP = (-4, 6)  # decimal notation for 1e-4 <= |x| < 1e6


def _finite(x) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _exp10(x: float) -> int:
    return int(math.floor(math.log10(abs(x)))) if x else 0


def _power(e: int, ascii: bool) -> str:
    return f"e{e}" if ascii else f" × 10{str(e).translate(_SUP)}"


def _fixed(x: float, decimals: int) -> str:
    s = f"{x:.{max(decimals, 0)}f}"
    if decimals < 0:  # round to tens, hundreds: keep the integer's digits honest
        q = 10 ** (-decimals)
        s = f"{round(x / q) * q:.0f}"
    return "0" + s[2:] if s.startswith("-0") and float(s) == 0 else s


def sig(x, n: int = 4, ascii: bool = False) -> str:
    """x to n significant digits; a power of ten only outside 1e-4 .. 1e6."""
    if not _finite(x):
        return "–" if not ascii else "-"
    x = float(x)
    if x == 0:
        return "0"
    e = _exp10(x)
    if PLAIN_EXP[0] <= e < PLAIN_EXP[1]:
        return _fixed(x, n - 1 - e)
    m = x / 10 ** e
    return f"{m:.{n - 1}f}" + _power(e, ascii)


def num(x, n: int = 4, ascii: bool = False) -> str:
    """A number without an error: integers as integers, else :func:`sig` (n digits)."""
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    return sig(x, n, ascii)


def decimals_for(std, digits: int = 2) -> int:
    """The decimal place at which an error of `std` is given to `digits` significant digits."""
    return digits - 1 - _exp10(float(std))


def pm(value, std, digits: int = 2, ascii: bool = False, unit: str = "") -> str:
    """``value ± std`` with the error to `digits` significant digits (1 σ).

    Without a usable error the value is printed to 6 significant digits.
    """
    u = f" {unit}" if unit else ""
    if not _finite(value):
        return ("–" if not ascii else "-")
    value = float(value)
    if not _finite(std) or float(std) <= 0:
        return sig(value, 6, ascii) + u
    std = float(std)
    d = decimals_for(std, digits)
    # round the error first: 0.0000996 at 2 digits is 0.00010, one decimal fewer
    std_r = round(std, d)
    if std_r and _exp10(std_r) > _exp10(std):
        d -= 1
    sep = " +/- " if ascii else " ± "
    big = max(abs(value), std)
    e = _exp10(big)
    if PLAIN_EXP[0] <= e < PLAIN_EXP[1] and d <= 12:
        return f"{_fixed(value, d)}{sep}{_fixed(std, d)}{u}"
    # shared power of ten
    s = 10.0 ** e
    dd = d + e
    body = f"{_fixed(value / s, dd)}{sep}{_fixed(std / s, dd)}"
    return f"({body}){_power(e, ascii)}{u}"


def interval(lo, hi, std=None, level: float = 95, ascii: bool = False, unit: str = "") -> str:
    """``"95 %: lo … hi"``: named by its level; as many digits as the error gives, and
    more when needed so that the two ends never print the same."""
    dots = " ... " if ascii else " … "
    if not (_finite(lo) and _finite(hi)):
        return "–"
    lo, hi = float(lo), float(hi)
    width = abs(hi - lo)
    ref = float(std) if _finite(std) and float(std) > 0 else (width / 4 if width else abs(lo))
    if not ref:
        ref = 1.0
    d = decimals_for(ref, 2)
    e = _exp10(max(abs(lo), abs(hi)) or 1.0)
    u = f" {unit}" if unit else ""
    lev = f"{level:g} %: "
    if PLAIN_EXP[0] <= e < PLAIN_EXP[1]:
        while _fixed(lo, d) == _fixed(hi, d) and width > 0 and d < 15:
            d += 1
        return f"{lev}{_fixed(lo, d)}{dots}{_fixed(hi, d)}{u}"
    s = 10.0 ** e
    dd = d + e
    while _fixed(lo / s, dd) == _fixed(hi / s, dd) and width > 0 and dd < 15:
        dd += 1
    return f"{lev}({_fixed(lo / s, dd)}{dots}{_fixed(hi / s, dd)}){_power(e, ascii)}{u}"


def sigma_apart(value, std, other) -> str:
    """How many σ `value` lies from `other`, as a phrase: ``"0.4 σ below"``."""
    if not (_finite(value) and _finite(std) and _finite(other)) or float(std) <= 0:
        return ""
    z = (float(value) - float(other)) / float(std)
    side = "above" if z > 0 else "below"
    a = abs(z)
    txt = f"{a:.1f}" if a < 10 else f"{a:.0f}" if a < 1e4 else sig(a, 2)
    return f"{txt} σ {side}"


def percent(x, n: int = 2) -> str:
    """A fraction as a percentage to n significant digits: 0.0241 -> "2.4 %"."""
    if not _finite(x):
        return "–"
    return sig(100 * float(x), n) + " %"

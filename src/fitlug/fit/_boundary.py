"""Type and name checks at the library's boundary (issue 27): an unknown effect or
parameter name, a string where a list belongs, a noise of the wrong kind fail at once with
the list of valid choices, instead of silently fitting the base model or failing deep in
JAX."""

from __future__ import annotations

import math


def check_effects(effects, *, what: str = "effects") -> tuple[str, ...]:
    """`effects` as a tuple of catalog ids.

    Raises:
        TypeError: a string (one id must still be a list: ``["wheel_runout"]``) or a
            non-iterable, or a non-string id.
        ValueError: an unknown id (wrong case included), naming the valid ids.
    """
    from ..model.effects import CATALOG

    if isinstance(effects, str):
        raise TypeError(f"{what} must be a list of effect ids, e.g. [{effects!r}], not the "
                        f"string {effects!r}")
    try:
        ids = tuple(effects)
    except TypeError:
        raise TypeError(f"{what} must be a list of effect ids, got "
                        f"{type(effects).__name__}") from None
    for e in ids:
        if not isinstance(e, str):
            raise TypeError(f"{what}: effect ids are strings, got {type(e).__name__} {e!r}")
        if e not in CATALOG:
            near = [k for k in CATALOG if k.lower() == e.lower().replace("-", "_")]
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ValueError(f"{what}: unknown effect {e!r}{hint}; valid: {', '.join(CATALOG)}")
    return ids


def check_noise(noise) -> dict | None:
    """`noise` as {'lug': sigma, 'body': sigma} in mm: None stays None, a positive number
    serves both roles, a dict needs both roles.

    Raises:
        TypeError: another type.
        ValueError: a missing or unknown role, a value not finite and > 0.
    """
    if noise is None:
        return None
    if isinstance(noise, bool):
        raise TypeError("noise must be a positive number (mm) or {'lug': mm, 'body': mm}, "
                        "got a bool")
    if isinstance(noise, (int, float)) or type(noise).__name__ in ("float64", "float32"):
        noise = {"lug": float(noise), "body": float(noise)}
    if not isinstance(noise, dict):
        raise TypeError(f"noise must be a positive number (mm) or {{'lug': mm, 'body': mm}}, "
                        f"got {type(noise).__name__}")
    bad = [k for k in noise if k not in ("lug", "body")]
    if bad:
        raise ValueError(f"noise: unknown role {bad[0]!r}; valid: lug, body")
    missing = [k for k in ("lug", "body") if k not in noise]
    if missing:
        raise ValueError(f"noise: no value for role {missing[0]!r}; give both lug and body "
                         "(or one number for both)")
    out = {}
    for k, v in noise.items():
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise TypeError(f"noise[{k!r}] must be a number (mm), got {type(v).__name__}") \
                from None
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"noise[{k!r}] must be finite and > 0 mm, got {v}")
        out[k] = v
    return out


def check_free(free, names) -> list[str] | None:
    """`free` as a list of the model's parameter names (fit.json aliases resolved).

    Raises:
        TypeError: a string or a non-iterable.
        ValueError: an unknown name, naming the valid ones.
    """
    from ._names import ALIASES

    if free is None:
        return None
    if isinstance(free, str):
        raise TypeError(f"free must be a list of parameter names, e.g. [{free!r}], not a string")
    out = []
    for k in free:
        key = ALIASES.get(k, k) if isinstance(k, str) else k
        if key not in names:
            raise ValueError(f"free: unknown parameter {k!r}; valid: {', '.join(names)} "
                             f"(aliases: {', '.join(a for a, c in ALIASES.items() if c in names)})")
        out.append(key)
    return out

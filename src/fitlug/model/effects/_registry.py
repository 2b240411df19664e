"""The catalog as a registry: fitlug's own effects, then plugins.

Plugins come two ways: :func:`register_effect` (a notebook, a script) and Python entry
points of the group ``fitlug.effects`` (an installed package; each entry point names an
:class:`~fitlug.model.Effect` subclass), read once, at the catalog's first use, so that
``import fitlug`` stays cheap and a broken plugin fails where it is used, by its name.
"""

from __future__ import annotations

import hashlib
import inspect
import re
import sys

from ._base import Effect

GROUP = "fitlug.effects"
#: parameter names of the base model (MODEL.md §2): no effect may take one
_BASE_NAMES = frozenset({"v", "s0", "beta", "R", "D", "e", "x_off", "y_off", "sigma0",
                         "cx", "cy"})
_HOOKS = ("time_map", "speed", "slip", "top_dy", "bottom_dy", "body_dy", "image", "lug_lag",
          "memory", "link")
_ID = re.compile(r"^[a-z][a-z0-9_]*$")


class Catalog(dict):
    """id -> effect class, fitlug's in MODEL.md's order, then plugins in registration order.

    A dict whose first read loads the entry points of the group ``fitlug.effects``.
    """

    _loaded = False

    def _load(self) -> None:
        if not self._loaded:
            self._loaded = True  # first, so a plugin that reads the catalog does not recurse
            for ep in _entry_points():
                try:
                    cls = ep.load()
                except Exception as exc:  # noqa: BLE001 - re-raised with the plugin's name
                    raise ImportError(f"effect plugin {ep.name!r} ({ep.value}, entry point "
                                      f"group {GROUP!r}) could not be loaded: {exc}") from exc
                register_effect(cls, _where=f"entry point {ep.name!r} ({ep.value})")

    def __getitem__(self, k):
        self._load()
        return dict.__getitem__(self, k)

    def __contains__(self, k):
        self._load()
        return dict.__contains__(self, k)

    def __iter__(self):
        self._load()
        return dict.__iter__(self)

    def __len__(self):
        self._load()
        return dict.__len__(self)

    def get(self, k, default=None):
        self._load()
        return dict.get(self, k, default)

    def keys(self):
        self._load()
        return dict.keys(self)

    def values(self):
        self._load()
        return dict.values(self)

    def items(self):
        self._load()
        return dict.items(self)

    def __repr__(self):
        self._load()
        return f"Catalog({', '.join(dict.keys(self))})"


CATALOG = Catalog()
_BUILTIN: set[str] = set()


def _entry_points():
    from importlib.metadata import entry_points

    return list(entry_points(group=GROUP))


def _builtin(*classes) -> None:
    for cls in classes:
        dict.__setitem__(CATALOG, cls.id, cls)
        _BUILTIN.add(cls.id)


def register_effect(cls: type[Effect], *, replace: bool = False, _where: str = "") -> type[Effect]:
    """Add an effect to the catalog: the fit, the explanation, the posterior, the simulator
    and the report then know it by its ``id``.

    Usable as a class decorator. The class is checked here, so that a mistake is named at
    once rather than deep inside a compiled model.

    Args:
        cls: a subclass of :class:`fitlug.model.Effect` with ``id`` (lower case, digits and
            ``_``), ``defaults`` (parameter -> identity value) and ``scales`` (parameter ->
            typical size, same names) and at least one hook (``speed``, ``slip``,
            ``top_dy``, ``bottom_dy``, ``body_dy``, ``image``, ``time_map``).
        replace: allow a new class under an id already registered (an edited effect in a
            notebook); fitlug's own effects cannot be replaced.

    Returns:
        cls, unchanged.

    Raises:
        TypeError: cls is not an Effect subclass, or lacks a field or a hook.
        ValueError: the id or a parameter name is taken, or the id is malformed.
    """
    where = f" ({_where})" if _where else ""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError(f"register_effect{where}: {cls!r} is not a subclass of fitlug.model.Effect")
    eid = getattr(cls, "id", None)
    if not isinstance(eid, str) or not _ID.match(eid):
        raise ValueError(f"register_effect{where}: {cls.__name__}.id must be a lower-case "
                         f"identifier such as 'belt_wear', not {eid!r}")
    for field in ("defaults", "scales"):
        if not isinstance(getattr(cls, field, None), dict) or not getattr(cls, field):
            raise TypeError(f"register_effect{where}: {cls.__name__}.{field} must be a "
                            "non-empty dict parameter name -> number")
    if set(cls.defaults) != set(cls.scales):
        raise TypeError(f"register_effect{where}: {cls.__name__}.defaults and .scales name "
                        f"different parameters: {sorted(cls.defaults)} vs {sorted(cls.scales)}")
    if not any(getattr(cls, h, None) is not None for h in _HOOKS):
        raise TypeError(f"register_effect{where}: {cls.__name__} defines no hook; one of "
                        f"{', '.join(_HOOKS)}")
    if cls.image is not None and not isinstance(getattr(cls, "order", None), (int, float)):
        cls.order = 100  # after fitlug's image effects (the order the light takes)
    bad = set(cls.fixed_in_fit) - set(cls.defaults)
    if bad:
        raise TypeError(f"register_effect{where}: {cls.__name__}.fixed_in_fit names "
                        f"{sorted(bad)}, not among its parameters {list(cls.defaults)}")
    CATALOG._load()
    old = dict.get(CATALOG, eid)
    if old is not None and old is not cls:
        if eid in _BUILTIN:
            raise ValueError(f"register_effect{where}: {eid!r} is one of fitlug's own effects")
        if not replace:
            raise ValueError(f"register_effect{where}: an effect {eid!r} is already registered "
                             f"({old.__module__}.{old.__qualname__}); pass replace=True to "
                             "replace it")
    taken = {k: e for e, c in dict.items(CATALOG) if e != eid for k in c.defaults}
    clash = (set(cls.defaults) & _BASE_NAMES) | (set(cls.defaults) & set(taken))
    if clash:
        k = sorted(clash)[0]
        owner = "the base model" if k in _BASE_NAMES else f"effect {taken[k]!r}"
        raise ValueError(f"register_effect{where}: parameter {k!r} of {eid!r} is already a "
                         f"parameter of {owner}; prefix it with the effect's short name")
    dict.__setitem__(CATALOG, eid, cls)
    if old is not None and old is not cls:
        _forget_compiled()
    return cls


def unregister_effect(effect_id: str) -> None:
    """Remove a plugin effect from the catalog (fitlug's own cannot be removed).

    Raises:
        ValueError: the id is fitlug's own or not registered.
    """
    if effect_id in _BUILTIN:
        raise ValueError(f"unregister_effect: {effect_id!r} is one of fitlug's own effects")
    if effect_id not in CATALOG:
        raise ValueError(f"unregister_effect: no effect {effect_id!r}; plugins: "
                         f"{', '.join(plugins()) or 'none'}")
    dict.__delitem__(CATALOG, effect_id)
    _forget_compiled()


def plugins() -> list[str]:
    """The ids of registered plugin effects (not fitlug's own)."""
    return [e for e in CATALOG if e not in _BUILTIN]


def _forget_compiled() -> None:
    """A class replaced under the same id: programs traced with the old one must go (the
    layout names effects by id, so jit's own cache would serve the old trace)."""
    import jax

    from ... import _exported

    jax.clear_caches()
    _exported.forget()


def code_identity() -> str | None:
    """A digest of every plugin effect's code (the source files of its class and of its
    bases outside fitlug), for the keys of programs kept on disk; None when a plugin's
    source cannot be read (then nothing may be kept on disk)."""
    h = hashlib.sha256()
    for eid in plugins():
        cls = dict.__getitem__(CATALOG, eid)
        h.update(f"{eid}={cls.__module__}.{cls.__qualname__};".encode())
        for base in cls.__mro__:
            if base.__module__.split(".")[0] in ("fitlug", "builtins"):
                continue
            src = _source_of(base)
            if src is None:
                return None
            h.update(src)
    return h.hexdigest()


def _source_of(cls) -> bytes | None:
    """The bytes of the file defining cls (helpers beside it count too), else the class's
    own source (a notebook cell), else None."""
    mod = sys.modules.get(cls.__module__)
    path = getattr(mod, "__file__", None)
    if path:
        try:
            with open(path, "rb") as fh:
                return fh.read()
        except OSError:
            pass
    try:
        return inspect.getsource(cls).encode()
    except (OSError, TypeError):
        return None

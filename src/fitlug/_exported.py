"""Traced and lowered programs kept on disk across processes (JAX's public jax.export).

JAX's persistent compilation cache skips XLA's compilation in a new process, but not the
tracing and lowering of the Python function, which for the Levenberg-Marquardt solver
(optimistix, lineax) takes several seconds every time fitlug starts: the biggest single
cost of a warm run on a short recording. :func:`call` exports such a function once per
argument signature (jax.export: a serialised StableHLO module with a compatibility
guarantee), keeps it under the cache directory, and in later processes deserialises it
and calls it; the compilation of the deserialised module is then found in the persistent
compilation cache. The numbers are the same bit for bit (tests/test_exported.py).

The key is the function's name, its static arguments' repr, the shapes and dtypes of its
array arguments, the versions of jax and jaxlib, and a digest of the contents of
fitlug's own source files, so an edited or upgraded installation exports afresh (and a
fresh clone of the same code does not), and the
code of every plugin effect (each source added by :func:`add_identity`: the catalog's
digest of its plugins' files, so an edited user effect under the same id is never served
a program traced from its old code; a plugin whose source cannot be read turns the disk
off). Anything
unusual (a tracer or a non-array leaf among the arguments, an export or a read that fails,
FITLUG_NO_EXPORT_CACHE=1) falls back to calling the function as it is.

Threads: a key's module is exported (or read) and first called (compiled) under a lock of
its own, so a program that another thread is compiling is waited for, not compiled twice
(:mod:`fitlug.cli._prewarm` compiles the later stages' programs beside the solver's on a
first run). :func:`on_export` names a callback called, in the exporting thread, just before
a freshly exported module is compiled: the sign that this run is compiling.
"""

from __future__ import annotations

import hashlib
import os
import threading

import jax
import numpy as np

from . import _jaxconfig

_MEMO: dict = {}  # key -> jitted call of the deserialised module, or None (fall back)
_MEMO_MAX = 16  # signatures kept in a process (a campaign fits many recordings in one)
STALE_DAYS = 30  # a module unused this long is removed when a new one is written
_SOURCE: list = []
_IDENTITIES: list = []  # callables -> str, or None when what they cover cannot be keyed
_LOCK = threading.Lock()  # guards _MEMO, _READY and _KEY_LOCKS
_KEY_LOCKS: dict = {}  # key -> the lock its export and first call are made under
_READY: set = set()  # keys whose jitted call has run once in this process (compiled)
_ON_EXPORT: list = []  # callbacks(name) before a freshly exported module's first call
#: name -> the thread that made a module's first call in this process (tests, benchmarks)
FIRST_CALLER: dict = {}


def forget() -> None:
    """Drop every module held in this process (a plugin effect replaced under its id)."""
    with _LOCK:
        _MEMO.clear()
        _READY.clear()


def on_export(callback) -> None:
    """Call callback(name) in the exporting thread just before a module exported in this
    process (not read from disk) is first called, i.e. compiled; exceptions it raises are
    ignored. Remove it with :func:`remove_on_export`."""
    with _LOCK:
        if callback not in _ON_EXPORT:
            _ON_EXPORT.append(callback)


def remove_on_export(callback) -> None:
    """Stop calling `callback` (see :func:`on_export`)."""
    with _LOCK:
        if callback in _ON_EXPORT:
            _ON_EXPORT.remove(callback)


def add_identity(fn) -> None:
    """Make fn() (a str, or None to keep nothing on disk) part of every key: a later
    stage's code that programs depend on (the catalog's plugin effects)."""
    if fn not in _IDENTITIES:
        _IDENTITIES.append(fn)


def _tree_digest(base: str) -> str:
    """A digest of the contents of every .py file under `base`, by relative path (4 ms
    for fitlug's 1.6 MB)."""
    h = hashlib.sha256()
    for dirpath, dirnames, files in os.walk(base):
        dirnames.sort()
        for f in sorted(files):
            if f.endswith(".py"):
                path = os.path.join(dirpath, f)
                with open(path, "rb") as fh:
                    data = fh.read()
                h.update(f"{os.path.relpath(path, base)}:{len(data)}:".encode())
                h.update(data)
    return h.hexdigest()


def _source_identity() -> str:
    """fitlug's own sources' digest, once a process: an edit exports afresh, a fresh clone
    or reinstall of the same code (new mtimes) does not."""
    if not _SOURCE:
        _SOURCE.append(_tree_digest(os.path.dirname(os.path.abspath(__file__))))
    return _SOURCE[0]


def cache_dir() -> str:
    """A folder inside the compile cache's (JAX's own cache reads only its *-cache files),
    so that FITLUG_CACHE_DIR moves or empties both."""
    return os.path.join(_jaxconfig._cache_dir(), "exported")


def _enabled() -> bool:
    return (os.environ.get("FITLUG_NO_EXPORT_CACHE") != "1"
            and os.environ.get("FITLUG_NO_JAX_CACHE") != "1")


def call(name: str, fn, static: tuple, *args):
    """fn(*args, *static), through an exported module kept on disk.

    fn must return a tuple (of arrays, or of pytrees of arrays such as dicts); `args` are
    pytrees of arrays (traced), `static` the trailing arguments fixed at trace time (their
    repr is part of the key).
    """
    leaves, treedef = jax.tree_util.tree_flatten(args)
    if not _enabled() or not all(isinstance(x, (jax.Array, np.ndarray)) for x in leaves) \
            or any(isinstance(x, jax.core.Tracer) for x in leaves):
        return fn(*args, *static)
    import jaxlib

    extra = [f() for f in _IDENTITIES]
    if any(x is None for x in extra):
        return fn(*args, *static)
    sig = repr((name, static, str(treedef), [(x.shape, str(x.dtype)) for x in leaves],
                jax.__version__, jaxlib.__version__, jax.default_backend(),
                _source_identity(), *extra))
    key = hashlib.sha256(sig.encode()).hexdigest()[:32]
    with _LOCK:
        f = _MEMO.get(key, False)
        ready = key in _READY
    if f is not False and ready:
        return fn(*args, *static) if f is None else f(*leaves)
    with _LOCK:
        key_lock = _KEY_LOCKS.setdefault(key, threading.Lock())
    with key_lock:  # another thread exporting or compiling this key: wait for it
        with _LOCK:
            f = _MEMO.get(key, False)
        exported = False
        if f is False:
            f, exported = _load_or_export(name, key, fn, static, treedef, leaves)
            with _LOCK:
                while len(_MEMO) >= _MEMO_MAX:
                    old = next(iter(_MEMO))
                    _MEMO.pop(old)
                    _READY.discard(old)
                _MEMO[key] = f
        if f is None:
            return fn(*args, *static)
        with _LOCK:
            ready = key in _READY
        if ready:
            return f(*leaves)
        if exported:
            with _LOCK:
                hooks = list(_ON_EXPORT)
            for cb in hooks:
                try:
                    cb(name)
                except Exception:  # noqa: BLE001 - a listener never breaks a fit
                    pass
        out = f(*leaves)
        with _LOCK:
            _READY.add(key)
            FIRST_CALLER.setdefault(name, threading.current_thread().name)
        return out


def _load_or_export(name, key, fn, static, treedef, leaves):
    """(the jitted call of the module, whether it was exported now) or (None, False)."""
    from jax import export

    path = os.path.join(cache_dir(), f"{name}-{key}.jaxexport")
    exp = None
    fresh = False
    if os.path.exists(path):
        try:
            with open(path, "rb") as fh:
                exp = export.deserialize(bytearray(fh.read()))
            os.utime(path)  # in use: not stale
        except Exception:  # a truncated or foreign file: export afresh
            exp = None
    if exp is None:
        def flat_fn(*xs):
            out = fn(*jax.tree_util.tree_unflatten(treedef, xs), *static)
            return tuple(out)

        try:
            exp = export.export(jax.jit(flat_fn))(*leaves)
            blob = exp.serialize()
            fresh = True
        except Exception:  # e.g. a host callback in the program: not exportable
            return None, False
        try:
            os.makedirs(cache_dir(), exist_ok=True)
            tmp = f"{path}.{os.getpid()}.tmp"
            with open(tmp, "wb") as fh:
                fh.write(blob)
            os.replace(tmp, path)
            _prune(name)
        except OSError:  # read-only cache: the module still serves this process
            pass
    def program(*xs):
        return exp.call(*xs)

    program.__name__ = program.__qualname__ = name  # profiles name it (not "call")
    return jax.jit(program), fresh


def _prune(name: str) -> None:
    """Remove this function's modules unused for STALE_DAYS (every new shape of recording,
    and every edit of fitlug's source, writes a new one of ~100-200 KB)."""
    import glob
    import time

    old = time.time() - STALE_DAYS * 86400
    for f in glob.glob(os.path.join(cache_dir(), f"{name}-*.jaxexport")):
        try:
            if os.path.getmtime(f) < old:
                os.remove(f)
        except OSError:
            pass

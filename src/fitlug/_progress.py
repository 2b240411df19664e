"""Progress of long work, and the compiles it pays, for whoever listens (issue 43, item 5).

Library code says what it is doing with :func:`note` (a record of the logger
``fitlug.progress`` at INFO, its stage in ``record.stage``): silent unless a handler is
set, as the command line does (``fitlug.cli._common.progress_lines``) and as a library
user may (``logging.basicConfig(level=logging.INFO)``).

:func:`watch_compiles` tells a callback when JAX compiles a program for real: a backend
compile that the persistent cache (fitlug._jaxconfig) did not answer. It listens to
``jax.monitoring``'s events: every backend compile records
``/jax/core/compile/backend_compile_duration``, a persistent-cache hit records
``/jax/compilation_cache/cache_hits`` just before it; a compile without a hit is a real one.
"""

from __future__ import annotations

import logging
import threading

LOG = logging.getLogger("fitlug.progress")

_BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
_CACHE_HIT = "/jax/compilation_cache/cache_hits"
_lock = threading.Lock()
_state = {"registered": False, "hits": 0, "hits_seen": 0}
_callbacks: list = []


def note(stage: str, message: str, *, last: bool = False) -> None:
    """One progress record of `stage` ("fitting", "explaining", "sampling", ...); `last`:
    the stage's closing count (a listener that thins the lines keeps it)."""
    if LOG.isEnabledFor(logging.INFO):
        LOG.info(message, extra={"stage": stage, "last": last})


def _on_event(event: str, **kwargs) -> None:
    if event == _CACHE_HIT:
        with _lock:
            _state["hits"] += 1


def _on_duration(event: str, seconds: float, **kwargs) -> None:
    if event != _BACKEND_COMPILE:
        return
    with _lock:
        hit = _state["hits"] > _state["hits_seen"]
        _state["hits_seen"] = _state["hits"]
        callbacks = list(_callbacks)
    if not hit:
        for cb in callbacks:
            cb(str(kwargs.get("fun_name", "")), float(seconds))


def watch_compiles(callback) -> None:
    """Call callback(function name, seconds) after each real compile (not a cache hit).

    The jax.monitoring listeners are registered once per process; :func:`unwatch_compiles`
    removes the callback."""
    import jax.monitoring as mon

    with _lock:
        if not _state["registered"]:
            mon.register_event_listener(_on_event)
            mon.register_event_duration_secs_listener(_on_duration)
            _state["registered"] = True
        _state["hits_seen"] = _state["hits"]
        _callbacks.append(callback)


def unwatch_compiles(callback) -> None:
    """Stop calling `callback` (see :func:`watch_compiles`)."""
    with _lock:
        if callback in _callbacks:
            _callbacks.remove(callback)

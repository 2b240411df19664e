"""JAX set-up shared by every numerical module: float64 and the persistent compile cache.

Import this module before building any JAX array; it is idempotent.
"""

from __future__ import annotations

import os

import jax

jax.config.update("jax_enable_x64", True)


def _cache_dir() -> str:
    base = os.environ.get("FITLUG_CACHE_DIR")
    if base:
        return base
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(xdg, "fitlug", "jax")


if os.environ.get("FITLUG_NO_JAX_CACHE") != "1":
    try:
        path = _cache_dir()
        os.makedirs(path, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", path)
        # cache every compiled function: our fits compile in ~0.1-5 s each
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    except Exception:  # read-only home etc.: run without the cache
        pass

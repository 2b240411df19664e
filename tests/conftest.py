"""Strict test environment: float64 JAX, a private compile cache, helpers on sys.path."""

import os
import sys

os.environ.setdefault("FITLUG_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache",
                                                        "fitlug", "jax-tests"))
sys.path.insert(0, os.path.dirname(__file__))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

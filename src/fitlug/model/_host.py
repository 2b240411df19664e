"""The model evaluated from host code (the explanation's readings, the simulator, the
report's positions): one compiled program per function and shape (issue 43).

Called eagerly, a JAX function dispatches each of its operations as a program of its own,
compiled (or read from the persistent cache) once per shape: the straight runs' reading of
one engine recording ran ~150 of them, 2.5 s with a warm cache and 13 s with a cold one,
for 0.2 s of arithmetic. Here each evaluation is one jit-compiled program; times are
padded to bucketed lengths (:func:`fitlug.model._buckets.bucket`, the padding repeats the
first time and is cut off), so that a reading at another number of times reuses it.

The values are the eager functions' to rounding: XLA fuses the operations and may round
them in another order (~1e-15 relative; tests/test_host.py holds them to 1e-12).
"""

from __future__ import annotations

import jax
import numpy as np

from ._buckets import bucket
from ._model import (integrate, kinematics, positions, predict, sampled_from_nodes,
                     speed_basis_values)

_integrate = jax.jit(integrate)
_kinematics = jax.jit(kinematics)
_sampled = jax.jit(sampled_from_nodes)
_positions = jax.jit(positions)
_speed_values = jax.jit(speed_basis_values)
_predict = jax.jit(predict)


def _padded(t):
    t = np.asarray(t, float)
    flat = t.ravel()
    n = flat.shape[0]
    nb = bucket(n)
    if nb > n:
        flat = np.concatenate([flat, np.full(nb - n, flat[0] if n else 0.0)])
    return jax.device_put(flat), n, t.shape


def integrate_host(p: dict, lay):
    """:func:`fitlug.model.integrate` as one compiled program: (X, psi, dX/dt, dpsi/dt)."""
    return _integrate(p, lay)


def kinematics_host(p: dict, lay, t, nodes=None) -> dict:
    """:func:`fitlug.model.kinematics` at times `t` (any shape), numpy arrays of t's shape;
    `nodes` as :func:`integrate_host` gives them (integrated here when None)."""
    if nodes is None:
        nodes = _integrate(p, lay)
    tp, n, shape = _padded(t)
    out = jax.device_get(_kinematics(p, lay, tp, nodes))
    return {k: np.asarray(v)[:n].reshape(shape) for k, v in out.items()}


def sampled_host(p: dict, lay, nodes):
    """:func:`fitlug.model.sampled_from_nodes` as one compiled program."""
    return _sampled(p, lay, nodes)


def positions_host(p: dict, lay, Xl, psil, Xb, psib):
    """:func:`fitlug.model.positions` as one compiled program."""
    return _positions(p, lay, Xl, psil, Xb, psib)


def predict_host(p: dict, lay):
    """:func:`fitlug.model.predict` as one compiled program (the simulator's truth, the
    report's model positions): (lug_x, lug_y, body_x, body_y)."""
    return _predict(p, lay)


def speed_values_host(lay, c):
    """:func:`fitlug.model._model.speed_basis_values` as one compiled program."""
    return _speed_values(lay, c)

"""After the least-squares solve: the undamped Gauss-Newton polish of a dense fit that
Levenberg-Marquardt left at its step limit, and the parameters' covariance (J^T J)^-1 as a
pseudo-inverse, from the Jacobian or from the normal matrix of the long recordings.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..model._physics import beta_max
from ._lsq import LsqOutput
from ._residuals import Packing, jacobian, residuals


def inverse_norms(n: np.ndarray) -> np.ndarray:
    """1 / n for the column scaling of a pseudo-inverse, 0 where a column is zero (a
    parameter that does not act here, e.g. an effect's at a degenerate state: it gets the
    pseudo-inverse's zero, not 0 * inf = NaN in every entry)."""
    return np.where(n > 0, 1.0 / np.where(n > 0, n, 1.0), 0.0)


def _physical(p) -> bool:
    """Whether the slip law of `p` lies in its physical range (the solver's bounds)."""
    if "s0" not in p or "beta" not in p:
        return True
    b = float(np.ravel(p["beta"])[0])
    return 0.0 <= b <= float(np.ravel(beta_max(p["s0"]))[0])


@eqx.filter_jit
def _residuals_jacobian(flat, fixed, lay, obs, packing: Packing):
    return residuals(packing.unpack(flat, fixed), lay, obs), jacobian(flat, fixed, lay, obs,
                                                                          packing)


def gauss_newton_polish(out: LsqOutput, lay, obs, *, tol: float, max_iter: int = 12,
                        rcond: float = 1e-12) -> tuple[LsqOutput, float]:
    """Undamped Gauss-Newton steps (pseudo-inverse, halved until chi^2 drops) from `out`.

    For a dense fit that Levenberg-Marquardt left unconverged at its step limit: in a long,
    nearly flat valley (a cruise-only recording, where the slip slope beta and the speed
    spline trade against s0) LM's damping crawls along the valley floor, while one full
    Gauss-Newton step of the nearly linear problem lands on its minimum. Returns the polished
    output (converged when the chi^2 a further full step could remove is below `tol`) and
    that remaining decrement."""
    fixed = {k: jnp.asarray(v, float) for k, v in out.params.items()
             if k not in out.packing.names}
    flat, J, r = np.asarray(out.flat, float), np.asarray(out.J, float), np.asarray(out.r, float)
    chi2, dec, steps = float(r @ r), np.inf, out.steps
    for it in range(max_iter + 1):
        d = inverse_norms(np.linalg.norm(J, axis=0))
        z = np.linalg.lstsq(J * d, r, rcond=rcond)[0]
        dec = float(((J * d).T @ r) @ z)
        if not np.isfinite(dec) or dec < tol or it == max_iter:
            break
        step, t, moved = -z * d, 1.0, False
        while t > 1.0 / 256:
            r_t, J_t = _residuals_jacobian(flat + t * step, fixed, lay, obs, out.packing)
            r_t = np.asarray(r_t)
            if (np.all(np.isfinite(r_t)) and float(r_t @ r_t) < chi2
                    and _physical(out.packing.unpack(jnp.asarray(flat + t * step), fixed))):
                flat, J, r, chi2, moved = flat + t * step, np.asarray(J_t), r_t, float(r_t @ r_t), True
                break
            t /= 2
        steps += 1
        if not moved:
            break
    p = out.packing.unpack(jnp.asarray(flat), fixed)
    return out._replace(params=p, flat=flat, J=J, r=r, steps=steps,
                        converged=bool(dec < tol)), dec


def covariance(J: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """(J^T J)^-1 with a pseudo-inverse for directions the data do not constrain."""
    s = inverse_norms(np.sqrt(np.sum(J * J, 0)))
    Js = J * s
    A = Js.T @ Js  # one operand twice: BLAS's syrk (two copies went through gemm, ~20x)
    w, V = np.linalg.eigh(A)
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    return (V * inv) @ V.T * np.outer(s, s)


def covariance_normal(A: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """:func:`covariance` from the normal matrix J^T J instead of J (same pseudo-inverse)."""
    A = np.asarray(A)
    s = inverse_norms(np.sqrt(np.maximum(np.diag(A), 0.0)))
    As = A * np.outer(s, s)
    w, V = np.linalg.eigh(As)
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    return (V * inv) @ V.T * np.outer(s, s)

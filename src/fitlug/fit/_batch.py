"""Fitting many recordings of one rig with one compiled solver.

Every compiled program (the Levenberg-Marquardt solve, its Jacobian, the covariance) is
keyed by the shapes of its arrays and the layout's static fields. Every fit runs on
bucketed shapes (:mod:`._buckets`: weightless samples, unread knots and markers, grid
nodes past the end), so recordings of one kind whose sizes fall in the same buckets share
their programs; :func:`fit_many` gives each group of recordings that share the static
structure (markers of each role, lugs on the belt, frame rate, effects) one common shape,
the group's largest bucket of each size (:func:`._buckets.at_least`), so the group
compiles once whatever its lengths. Each result is the recording's own fit, as
:func:`fitlug.fit.fit` gives it (to the solver's tolerance: the padding's zeros change
the sums' rounding).
"""

from __future__ import annotations

from . import _buckets
from ._problem import Problem, build_problem


def _signature(prob: Problem) -> tuple:
    lay = prob.lay
    return (lay.n_lug, lay.n_body, int(lay.n_belt), int(lay.n_contact), float(lay.L),
            round(float(lay.h), 12),
            lay.effects, prob.rec.sigma is None)


def fit_many(recordings, rig=None, *, effects=(), noise: dict | None = None,
             glitches: bool = True, **kw) -> list:
    """Fit many recordings of one rig, compiling the solver once per group of recordings
    that share their markers (and once more for later batches of similar sizes).

    Each recording is fitted as :func:`fitlug.fit.fit` fits it (noise re-estimation,
    glitches), on shapes padded to the group's common sizes with samples of weight zero
    and parameters no sample reads: the one-by-one fit's numbers, to the solver's
    tolerance (chi^2 to 1e-10 relative).

    Args:
        recordings: Recording objects (an iterable).
        rig: their Rig (default: the reference rig).
        effects, noise, glitches, **kw: as for :func:`fitlug.fit.fit`.

    Returns:
        One FitResult per recording, in order.

    Raises:
        InputError: a recording that cannot be fitted (naming it), before any fit runs.
        FitError: a fit that does not converge.
    """
    from ..io import Rig
    from ._fit import finish_fit, fit_problem

    rig = Rig.reference(assumed=True) if rig is None else rig
    recordings = list(recordings)
    probs = [build_problem(rec, rig, effects=effects, noise=noise) for rec in recordings]
    groups: dict = {}
    for i, p in enumerate(probs):
        groups.setdefault(_signature(p), []).append(i)
    out = [None] * len(probs)
    for idx in groups.values():
        sizes = [_buckets.sizes(probs[i].lay) for i in idx]
        floor = {k: max(sz[k] for sz in sizes) for k in sizes[0]}
        with _buckets.at_least(floor):
            for i in idx:
                out[i] = finish_fit(fit_problem(probs[i], **kw), probs[i], noise=noise,
                                    glitches=glitches, **kw)
    return out

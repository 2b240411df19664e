"""On a first run, compile the later stages' programs while the solver's compiles (issue 43).

A recording of a kind this machine has not seen compiles about ten programs one after the
other: the Levenberg-Marquardt solver's (the largest: 4-6 s on 2 cores, most of it in
XLA, which releases the GIL), then the derived quantities', the glitch finder's, the
explanation's, the report's and the posterior's (together as long again). Their shapes
are known before the first fit: they are the recording's, its rig's and the base model's.
So when the solver's module has just been exported (:func:`fitlug._exported.on_export`:
this process is compiling, so the disk had nothing for this kind of recording), a daemon
thread builds the same problem, takes its data-derived start as if it were a fit, and runs
the later stages' own functions on it (discarding what they compute): each of their
programs is exported and compiled by the thread on the core the solver leaves free, and
the stages find it ready (:mod:`fitlug._exported` makes a stage wait for a program the
thread is compiling instead of compiling it twice).

Only the programs' shapes matter: the numbers the stages compute later are their own,
bit for bit. Where a stage's program differs from the base model's (an explained effect
changes the model) the thread's work was spent for nothing, on a first run only. A warm
run (every module on disk) never starts the thread. Anything the thread's steps raise is
ignored: a step only saves time.
"""

from __future__ import annotations

import threading

_THREADS: list = []


def arm(rec, rig, *, explain: bool = True, posterior: bool = True,
        report: bool = True) -> object:
    """Start the thread once the solver's module for `rec` is exported in this process;
    returns the callback to pass to :func:`disarm` when the fit is done. `explain`,
    `posterior`, `report`: whether the command runs those stages (without the posterior's
    chain, its marginal's Jacobian is still made: the least-squares identifiability)."""
    from .. import _exported

    started = threading.Event()

    def on_export(name: str) -> None:
        if name != "lsq_solve" or started.is_set():
            return
        started.set()
        t = threading.Thread(target=_run, args=(rec, rig, (explain, posterior, report)),
                             name="fitlug-prewarm",
                             daemon=True)
        _THREADS.append(t)
        t.start()

    _exported.on_export(on_export)
    return on_export


def disarm(callback) -> None:
    """Stop watching for the solver's export (the thread, if started, runs on)."""
    from .. import _exported

    _exported.remove_on_export(callback)


def join(timeout: float | None = None) -> None:
    """Wait for the threads started in this process (tests, benchmarks)."""
    for t in list(_THREADS):
        t.join(timeout)


def _start_result(rec, rig):
    """A FitResult of the base model at the recording's data-derived start: the shapes
    of the fit the command is computing, none of its numbers."""
    import numpy as np

    from ..fit import FitResult, build_problem
    from ..fit._fit import free_parameters
    from ..fit._residuals import Packing
    from ..io import Rig
    from ..io._coerce import as_recording, as_rig

    rig = as_rig(rig)  # as fitlug.fit takes them
    rig = Rig.reference(assumed=True) if rig is None else rig
    prob = build_problem(as_recording(rec, rig=rig), rig)
    p0 = dict(prob.p0)
    packing = Packing.of(p0, free_parameters(prob.lay))
    flat = np.asarray(packing.pack(p0), float)
    n_res = 2 * (prob.lay.lug_t.shape[0] + prob.lay.body_t.shape[0])
    return FitResult(problem=prob, params={k: np.asarray(v) for k, v in p0.items()},
                     packing=packing, flat=flat, cov=np.eye(len(flat)),
                     residuals=np.zeros(n_res), chi2=float(n_res),
                     dof=max(prob.n_valid - len(flat), 1), converged=True, steps=0)


def _steps(res, rig, stages=(True, True, True)) -> list:
    """The later stages' calls, in the order the command makes them; `stages`: whether
    the explanation, the posterior's chain and the report run."""
    explain, chain, draw = stages

    def derived():
        from ..fit._result import compute_quantities

        fixed = {k: v for k, v in res.params.items() if k not in res.packing.names}
        compute_quantities(res.params, res.packing, res.flat, res.cov, res.problem.lay,
                           rig.mass_kg, fixed, rig.drawbar_pull_N)

    def glitches():
        from ..fit._glitches import standardised_residuals

        standardised_residuals(res)

    def explanation():
        from ..explain._table import geometry

        geometry(res)

    def report():
        import jax
        import numpy as np

        from ..report._state import _raw_residuals, state_arrays

        state_arrays(res)
        if explain:  # the base fit's residuals beside the final's (the explanation's)
            _raw_residuals(res.problem, {k: jax.device_put(np.asarray(v))
                                         for k, v in res.params.items()})

    def posterior():
        import inspect

        from ..posterior._marginal import slip_law_parameters
        from ..posterior._sample import sample_posterior
        from ..posterior._tempering import tempered_marginal

        walkers = inspect.signature(sample_posterior).parameters["walkers"].default
        marg, _ = tempered_marginal(res, slip_law_parameters(res), batch=walkers // 2)
        if chain:
            marg.linearity_check()

    return [derived, glitches] + [explanation] * explain + [report] * draw + [posterior]


def _run(rec, rig, stages) -> None:
    try:
        res = _start_result(rec, rig)
    except Exception:  # noqa: BLE001 - the stages compile their programs themselves
        return
    for step in _steps(res, res.problem.rig, stages):
        try:
            step()
        except Exception:  # noqa: BLE001 - as above
            pass

"""On a first run, compile the later stages' programs beside the stage that runs (issue 43).

A recording of a kind this machine has not seen compiles about ten programs one after the
other: the Levenberg-Marquardt solver's (the largest: 5-6 s on 2 cores, most of it in
XLA, which releases the GIL), then the derived quantities', the glitch finder's, the
explanation table's, the report's and the posterior's (together as long again).

- When the solver's module has just been exported (:func:`fitlug._exported.on_export`:
  the disk had nothing for this kind of recording), a daemon thread builds the same
  problem, takes its data-derived start as if it were a fit and runs the fit's and the
  explanation's later calls on it (the derived quantities, the glitch search's model, the
  explanation's table), discarding what they compute: their programs depend only on the
  recording's and the rig's shapes and the base model, and compile on the core the
  solver leaves free.
- Once the explanation has given the final fit (its model is known only then: an
  explained effect changes it), the posterior's programs for that fit compile in a second
  thread while the command draws the report's early parts (:meth:`Prewarm.posterior`).

:mod:`fitlug._exported` makes a stage wait for a program a thread is compiling instead of
compiling it twice. Only the programs matter: the numbers the stages compute are their own,
bit for bit. A warm run (every module on disk) starts neither thread. Anything a thread's
steps raise is ignored: a step only saves time.
"""

from __future__ import annotations

import threading

_THREADS: list = []


class Prewarm:
    """What :func:`arm` returns: :meth:`disarm` once the fit is done, :meth:`posterior`
    once the explanation has given the final fit."""

    def __init__(self, rec, rig, explain: bool):
        self._args = (rec, rig, explain)
        self.started = threading.Event()

    def _on_export(self, name: str) -> None:
        if name != "lsq_solve" or self.started.is_set():
            return
        self.started.set()
        _start(_run, self._args, "fitlug-prewarm")

    def disarm(self) -> None:
        """Stop watching for the solver's export (the thread, if started, runs on)."""
        from .. import _exported

        _exported.remove_on_export(self._on_export)

    def posterior(self, final, chain: bool = True) -> None:
        """Where this run compiled its solver: the posterior's programs for `final` (the
        explained fit) compile in a thread while the command draws the report's early
        parts. `chain`: whether the chain runs (else only the marginal's Jacobian, for the
        least-squares identifiability)."""
        if self.started.is_set():
            _start(_posterior, (final, chain), "fitlug-prewarm-posterior")


def arm(rec, rig, *, explain: bool = True) -> Prewarm:
    """Start the thread once the solver's module for `rec` is exported in this process;
    `explain`: whether the command explains the fit (its table's program is made too)."""
    from .. import _exported

    handle = Prewarm(rec, rig, explain)
    _exported.on_export(handle._on_export)
    return handle


def join(timeout: float | None = None) -> None:
    """Wait for the threads started in this process (tests, benchmarks)."""
    for t in list(_THREADS):
        t.join(timeout)


def _start(target, args, name) -> None:
    t = threading.Thread(target=target, args=args, name=name, daemon=True)
    _THREADS.append(t)
    t.start()


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


def _steps(res, rig, explain: bool) -> list:
    """The fit's and the explanation's calls after the solver, in the command's order."""

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

    return [derived, glitches] + [explanation] * explain


def _run(rec, rig, explain) -> None:
    try:
        res = _start_result(rec, rig)
    except Exception:  # noqa: BLE001 - the stages compile their programs themselves
        return
    for step in _steps(res, res.problem.rig, explain):
        try:
            step()
        except Exception:  # noqa: BLE001 - as above
            pass


def _posterior(final, chain: bool) -> None:
    """The posterior's marginal of `final` as sample_posterior makes it, and its
    linearity check's passes (what is computed is discarded)."""
    try:
        import inspect

        from ..posterior._marginal import slip_law_parameters
        from ..posterior._sample import sample_posterior
        from ..posterior._tempering import tempered_marginal

        walkers = inspect.signature(sample_posterior).parameters["walkers"].default
        marg, _ = tempered_marginal(final, slip_law_parameters(final), batch=walkers // 2)
        if chain:
            marg.linearity_check()
    except Exception:  # noqa: BLE001 - the posterior compiles its programs itself
        pass

"""The report drawn by a process of its own (the `fit-lug` executable; issue 43).

The report needs matplotlib, corner and ArviZ (with xarray, pandas and scipy.stats):
~1.5 s CPU of imports in a warm run of the bundled recording. Imported in a thread of the
fitting process (:mod:`._preload`), they hold the GIL against the fit's own Python and
lengthened the fit by as much (measured: the fitting stage 3.5 s wall with the thread,
1.9 s without). A second process imports them on the machine's other core instead:

- :class:`ReportProcess` starts ``python -m fitlug.report._aside`` (a fresh interpreter, no
  fork of a process with JAX loaded) before the fit. The child imports the report's
  modules, reads a tiny netCDF file through ArviZ (its first read costs ~0.3 s), and waits.
- Once the fit is explained, :meth:`ReportProcess.draw_early` hands the child what the
  posterior does not change (a fit.json dict and the state's arrays without the
  posterior, in a scratch folder); the child draws those parts of the page
  (:data:`fitlug.report._page.EARLY`: trajectories, kinematics, residuals, least squares,
  the discrepancy's figures) while the posterior is sampled.
- Once fit.json, state.npz and posterior.nc are written, :meth:`ReportProcess.render`
  sends the folder; the child checks that the final files agree with the early parts'
  inputs wherever the posterior does not write (else it draws the page whole), runs
  :func:`fitlug.report.write_report` with the early parts (the report needs no JAX: it
  draws from those files) and answers with the page's path.
- On Linux the child draws neither the early parts nor the convergence section itself: it
  forks a copy of itself for each (it has no JAX, no threads: a fork shares its imports
  at no cost), which hands the HTML back through a pipe. The early parts' copy draws
  while the posterior is sampled; once the files are written the child draws the
  estimates, the slip and the posterior while the convergence section's copy reads
  posterior.nc through ArviZ and draws the traces, and the early parts' copy finishes.
  The page then waits only for what is not yet drawn (measured on the bundled
  recording: the command's wait for its report 1.1 -> 0.7 s). A copy that fails hands
  back nothing, and the child draws those parts itself.

The child is an accelerator only: if it cannot start, dies, or fails, :meth:`render`
writes the report in the calling process, which raises what the rendering raises (a
damaged folder's one-line error). The page is the same either way (tests/test_aside.py).
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

from ._copies import _Forked, _Parts, _forked, _peak_rss

log = logging.getLogger("fitlug.report")


class ReportProcess:
    """A child process that imports the report's modules now and renders a folder later."""

    def __init__(self):
        import fitlug

        # the child imports this very fitlug, wherever the caller found it (a source tree put
        # on sys.path by a script); an installed one it finds itself (a site folder first on
        # PYTHONPATH would go before the standard library)
        root = os.path.dirname(os.path.dirname(os.path.abspath(fitlug.__file__)))
        env = dict(os.environ)
        # its matrices are small; and it forks copies of itself (._copies), best without
        # BLAS worker threads
        for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(var, "1")
        if root not in _site_folders():
            env["PYTHONPATH"] = os.pathsep.join(
                [root] + [p for p in (env.get("PYTHONPATH"),) if p])
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "fitlug.report._aside"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True)
        except (OSError, ValueError, TypeError) as exc:  # no interpreter (sys.executable
            # empty in an embedded Python): the report is drawn here
            log.debug("report process not started: %s", exc)
            self.proc = None

        self.scratch = None  # a folder of the early parts' inputs, removed by close()
        self.answer = None  # the child's last answer (tests, benchmarks)

    def draw_early(self, fit_json: dict, arrays: dict, meta: dict) -> None:
        """Have the child draw the page's :data:`fitlug.report._page.EARLY` parts now, from
        a fit.json dict and the state's (arrays, meta) made without the posterior (written
        to a scratch folder as fit.json and state.npz are); returns at once."""
        if self.proc is None:
            return
        import tempfile

        from ..io import write_json
        from ._state import write_state

        self.scratch = tempfile.mkdtemp(prefix="fitlug-report-")
        write_json(os.path.join(self.scratch, "fit.json"), fit_json)
        write_state(self.scratch, arrays, meta, compressed=False)
        self._send({"early": self.scratch})

    def _send(self, msg: dict) -> None:
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
        except OSError as exc:  # the child is gone: render() draws the page here
            log.debug("report process gone: %s", exc)

    def render(self, out_dir) -> str:
        """Write DIR/report.html (see :func:`fitlug.report.write_report`); returns its path
        (DIR as given, as write_report returns it)."""
        out_dir = os.fspath(out_dir)
        answer = None
        if self.proc is not None:
            try:
                reply, _ = self.proc.communicate(
                    json.dumps({"out": os.path.abspath(out_dir)}) + "\n")
                answer = json.loads(reply.strip().splitlines()[-1]) if reply.strip() else None
            except (OSError, ValueError) as exc:
                log.debug("report process failed: %s", exc)
            finally:
                self.proc = None
        self.answer = answer
        self.close()
        if answer and "path" in answer:
            return os.path.join(out_dir, "report.html")
        if answer:
            log.debug("report process: %s", answer.get("error"))
        from ._page import write_report

        return write_report(out_dir)

    def close(self) -> None:
        """Stop the child if :meth:`render` was not called (a run that ended early), and
        remove the scratch folder."""
        if self.scratch is not None:
            import shutil

            shutil.rmtree(self.scratch, ignore_errors=True)
            self.scratch = None
        if self.proc is None:
            return
        proc, self.proc = self.proc, None
        try:
            proc.stdin.close()  # the child reads end-of-file and exits
            proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()


def _site_folders() -> set:
    """The site-packages folders a fresh interpreter puts on its path."""
    import site

    try:
        folders = list(site.getsitepackages()) + [site.getusersitepackages()]
    except AttributeError:  # a virtualenv of old without them
        folders = []
    return {os.path.abspath(f) for f in folders}


def _warm() -> None:
    """Imports and ArviZ's first read of a netCDF file, before the folder is known (the
    steps of the fitting process's import thread, :mod:`fitlug.report._preload`)."""
    from . import _page  # noqa: F401
    from ._preload import import_modules, warm_netcdf

    import_modules()
    warm_netcdf()


def _child() -> int:
    # as the executable (fitlug.cli.entry): xarray need not import dask to read a file
    for name in ("dask", "distributed"):
        sys.modules.setdefault(name, None)
    try:
        _warm()
    except Exception:  # noqa: BLE001 - the rendering imports again and says what failed
        pass
    early, inputs = None, None
    for line in sys.stdin:
        msg = json.loads(line)
        if "early" in msg:
            try:
                early = _forked_early(msg["early"])  # drawn beside this process
                if early is None:
                    early, inputs = _early(msg["early"])
                else:
                    inputs = _files(msg["early"])
            except Exception:  # noqa: BLE001 - drawn whole at the end instead
                early, inputs = None, None
            continue
        conv = None
        try:
            from ._page import convergence_part, write_report

            final = _files(msg["out"])  # read once: for the guard and the copy below
            used = early is not None and _same_inputs(inputs, final)
            inputs = None  # the early parts' inputs, no longer needed (memory)
            if not used and isinstance(early, _Forked):
                early.stop()
            # the convergence section (ArviZ's diagnostics and the traces) drawn beside the
            # posterior's other parts, by a second copy
            conv = _forked(lambda: convergence_part(*final, msg["out"]), ("convergence",))
            parts = _Parts([p for p in (early if used else None, conv) if p is not None])
            path = write_report(msg["out"], parts)
            reply = {"path": path, "early": "used" if used else
                     ("discarded" if early is not None else "none")}
            if used and isinstance(early, _Forked) and not early.drawn:
                reply["early"] = "failed"  # the forked process drew nothing: drawn here
            # the parts that forked copies drew (tests, benchmarks)
            reply["copies"] = sorted(k for f in (early if used else None, conv)
                                     if isinstance(f, _Forked) for k in f)
        except BaseException as exc:  # noqa: BLE001 - the caller draws it again and raises it
            reply = {"error": f"{type(exc).__name__}: {exc}"}
        # this process's peak and its copies' own memory: an upper bound of them all at once
        own = _peak_rss()
        reply["peak_rss_bytes"] = None if own is None else own + sum(
            f.peak or 0 for f in (early, conv) if isinstance(f, _Forked))
        sys.stdout.write(json.dumps(reply) + "\n")
        sys.stdout.flush()
        return 0
    return 0  # end of input: the run ended before its report


def _forked_early(folder: str):
    """The early parts of a scratch folder, drawn by a forked copy (:func:`_forked`)."""
    from ._page import EARLY

    return _forked(lambda: _early(folder)[0], EARLY)


def _files(folder: str):
    """(fit.json dict, state) of a folder: a scratch folder's, the early parts' inputs, or
    the final one's."""
    from ..io import read_json
    from ._state import load_state

    return read_json(os.path.join(folder, "fit.json")), load_state(folder)


def _early(folder: str):
    """(the early parts, their inputs) from a scratch folder of :meth:`draw_early`."""
    from ._page import early_parts

    fj, st = _files(folder)
    return early_parts(fj, st), (fj, st)


#: what the posterior changes in fit.json, and what names the run: not read by the early
#: parts (fitlug.report._page.EARLY; tests/test_aside.py draws them from both)
POSTERIOR_KEYS = frozenset({
    "slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance",
    "k_over_m_N_per_mm_kg", "uncertainty_method", "not_identifiable", "mcmc",
    "mcmc_skipped", "discrepancy_skipped", "run_id", "input_abs", "command", "date_utc"})


def _same_inputs(inputs, final) -> bool:
    """Whether the final fit.json and state.npz (`final`: :func:`_files` of the folder)
    agree with the early parts' inputs everywhere but in what the posterior adds or changes
    (a guard: otherwise the page is drawn whole)."""
    fj0, st0 = inputs
    fj, st = final
    keys = (set(fj0) | set(fj)) - POSTERIOR_KEYS
    if any(json.dumps(fj0.get(k), sort_keys=True) != json.dumps(fj.get(k), sort_keys=True)
           for k in keys):
        return False
    meta0, meta = (dict(m) for m in (st0["meta"], st["meta"]))
    for m in (meta0, meta):
        for k in ("run_id", "post_names", "post_parameters"):
            m.pop(k, None)
    if json.dumps(meta0, sort_keys=True) != json.dumps(meta, sort_keys=True):
        return False
    arrays0 = {k for k in st0 if k != "meta"}
    arrays = {k for k in st if k != "meta" and not k.startswith("post_")}
    return arrays0 == arrays and all(
        st0[k].dtype == st[k].dtype and st0[k].shape == st[k].shape
        and st0[k].tobytes() == st[k].tobytes() for k in arrays)


if __name__ == "__main__":
    os._exit(_child())  # nothing to tear down (fitlug.cli.exit_now)

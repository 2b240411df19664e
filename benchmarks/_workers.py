"""What the benchmarks that spawn worker processes set before spawning them, and what
their workers read of a run."""

from __future__ import annotations

import os


def one_thread_each() -> None:
    """One XLA and one BLAS thread per worker process (inherited by the spawned workers;
    a value already set is kept). With XLA's own thread pools, 16 workers on 16 cores took
    ~120 s a recording, ~15 s so; numpy's OpenBLAS also starts a thread per core in every
    worker (issue 42's device sweeps: a median 171 s a recording, then 60 s with one)."""
    os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                                       "intra_op_parallelism_threads=1")
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def report_process_peaks() -> list:
    """A list that gains the peak resident memory (bytes) of each report process
    (fitlug.report._aside) this worker's `fit-lug` runs use, from its answer; stays empty
    where the code has none (an older commit) or the run draws its report in-process."""
    peaks: list = []
    try:
        from fitlug.report import _aside
    except ImportError:
        return peaks
    render = _aside.ReportProcess.render

    def spy(self, out_dir):
        path = render(self, out_dir)
        peaks.append((self.answer or {}).get("peak_rss_bytes") or 0)
        return path

    _aside.ReportProcess.render = spy
    return peaks

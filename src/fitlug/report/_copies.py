"""Parts of the report drawn by forked copies of the report process (:mod:`._aside`).

The report process has no JAX and no threads when it forks, so a copy shares its imports
at no cost; a copy draws a dict of the page's parts, hands it back through a pipe as JSON
and ends without teardown. :class:`_Forked` is one copy's parts (a lookup waits for them),
:class:`_Parts` several copies' (a lookup waits only for the copy that draws that part).
A copy that fails hands back nothing: the page then draws those parts itself.
"""

from __future__ import annotations

import json
import os
import select
import signal
import sys
import time
from collections.abc import Mapping

#: the longest a page waits for a copy's parts (its drawing takes ~1 s on the bundled
#: recording, tens of seconds on the longest a report process draws); past it the copy
#: is ended and the page draws those parts itself
WAIT_S = 600.0


def _read_until(fd: int, deadline: float):
    """All of a pipe's bytes up to its end, closing it; None (closed) if `deadline`
    (time.monotonic) passes first."""
    chunks = []
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                return b"".join(chunks)
            chunks.append(chunk)
    finally:
        os.close(fd)


def _peak_rss():
    """This process's peak resident memory in bytes (Linux's VmHWM), or None elsewhere."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


class _Forked(Mapping):
    """The parts a forked copy of this process draws (:func:`_forked`) while this one goes
    on; a lookup waits for them. Empty where the copy failed or hung (the page then draws
    them itself)."""

    def __init__(self, fd: int, pid: int | None, keys=()):
        self._fd, self._pid = fd, pid
        self.keys_drawn = tuple(keys)  # what it draws (known before it is done)
        self._parts = None
        self.peak = None  # the copy's own resident memory (not shared), bytes

    def _get(self) -> dict:
        if self._parts is None:
            data = _read_until(self._fd, time.monotonic() + WAIT_S)
            if data is None:  # a copy that hangs: ended, its parts drawn by the page
                self._kill()
                data = b""
            if self._pid is not None:
                try:
                    os.waitpid(self._pid, 0)
                except OSError:
                    pass
            try:
                got = json.loads(data) if data else {}
            except ValueError:
                got = {}
            self._parts = got.get("parts") or {}
            self.peak = got.get("peak_rss_bytes")
        return self._parts

    @property
    def drawn(self) -> bool:
        return bool(self._get())

    def stop(self) -> None:
        """Discard the parts: end the copy (the final files did not match their inputs)."""
        if self._parts is None:
            self._kill()
            self._get()
            self._parts = {}

    def _kill(self) -> None:
        try:
            if self._pid is not None:
                os.kill(self._pid, signal.SIGKILL)
        except OSError:
            pass

    def __getitem__(self, key):
        return self._get()[key]

    def __iter__(self):
        return iter(self._get())

    def __len__(self) -> int:
        return len(self._get())


class _Parts(Mapping):
    """Parts from several :class:`_Forked` copies; a lookup waits only for the copy that
    draws that part."""

    def __init__(self, sources: list):
        self._sources = sources

    def _source(self, key):
        for src in self._sources:
            if not isinstance(src, _Forked) or key in src.keys_drawn:
                if key in src:
                    return src
        return None

    def __contains__(self, key) -> bool:
        return self._source(key) is not None

    def __getitem__(self, key):
        src = self._source(key)
        if src is None:
            raise KeyError(key)
        return src[key]

    def __iter__(self):
        seen = []
        for src in self._sources:
            seen += [k for k in src if k not in seen]
        return iter(seen)

    def __len__(self) -> int:
        return len(list(iter(self)))


def _forked(draw, keys):
    """A :class:`_Forked` running draw() (a dict of parts) in a forked copy of this
    process, or None where this process may not fork (not Linux, or JAX loaded: a process
    with JAX's threads is never forked): then the caller draws them itself."""
    if not sys.platform.startswith("linux") or "jax" in sys.modules:
        return None
    import gc

    # the objects alive now into the collector's permanent generation: a collection in the
    # copy would otherwise write to every one of them and copy their pages
    gc.freeze()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the copy: draw, hand the HTML over, end without teardown
        code = 0
        try:
            os.close(r)
            # off the child's stdin and stdout: the command reads the child's answer until
            # its stdout closes, which a copy left running must not hold open
            null = os.open(os.devnull, os.O_RDWR)
            os.dup2(null, 0)
            os.dup2(null, 1)
            data = json.dumps({"parts": draw(), "peak_rss_bytes": _private_rss()}).encode()
            with os.fdopen(w, "wb") as fh:
                fh.write(data)
        except BaseException:  # noqa: BLE001 - the page draws them itself
            code = 1
        os._exit(code)
    os.close(w)
    return _Forked(r, pid, keys)


def _private_rss():
    """The resident memory this process does not share with its parent (Linux's
    smaps_rollup: Private_Clean + Private_Dirty), in bytes: a forked copy's own share,
    taken when it has drawn (its figures' memory freed to the allocator, not the system);
    its VmHWM where that is not readable."""
    try:
        total = 0
        with open("/proc/self/smaps_rollup", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(("Private_Clean:", "Private_Dirty:")):
                    total += int(line.split()[1]) * 1024
        return total or _peak_rss()
    except (OSError, ValueError, IndexError):
        return _peak_rss()

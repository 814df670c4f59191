"""One solver thread for the editor: jobs run one at a time, and a newer request replaces a waiting one.

A Session is not thread-safe, so every job (a function of the engine) runs
on this one thread. Requests come in *channels* (one per websocket
connection, one for the JSON API): a channel holds at most one waiting job,
and a new job replaces it; the replaced job's future fails with Superseded
(the page gets ``{"dropped": true}``, the API 409). So while the solver is
busy, a drag's intermediate positions are dropped, never queued: the next
solve is always for the newest one. Channels waiting together are served in
the order they started waiting.
"""
from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from concurrent.futures import Future

log = logging.getLogger("skelfem")


def one_openmp_thread() -> None:
    """Make OpenMP run one thread on the calling thread, as Gmsh sets it on the main thread.

    OpenMP's thread count is per thread: a new thread starts with the machine's
    default (all cores), and Gmsh meshing there in parallel does not give the
    same mesh twice, so the editor's mesh would differ from `skelfem simulate`'s.
    """
    import ctypes
    try:
        ctypes.CDLL("libgomp.so.1").omp_set_num_threads(1)
    except (OSError, AttributeError):
        pass


class Superseded(Exception):
    """A newer request of the same channel replaced this one before it ran."""


class Closed(Exception):
    """The worker has stopped."""


class Worker:
    """Runs ``job(engine)`` on its own thread, latest-wins per channel."""

    def __init__(self, engine, on_error=None):
        self.engine = engine
        self.on_error = on_error              # called on the thread after a job raised an unexpected error
        self._pending: OrderedDict = OrderedDict()
        self._cond = threading.Condition()
        self._closed = False
        self._running = None                  # the future of the job being run, if any
        self.dropped = 0                      # jobs replaced before they ran
        self._thread = threading.Thread(target=self._run, name="skelfem-solver", daemon=True)
        self._thread.start()

    def submit(self, channel, job) -> Future:
        """Queue job for channel, replacing (and failing with Superseded) the job waiting there."""
        fut: Future = Future()
        with self._cond:
            if self._closed:
                fut.set_exception(Closed("the editor is shutting down"))
                return fut
            old = self._pending.pop(channel, None)
            if old is not None:
                self.dropped += 1
                old[1].set_exception(Superseded())
            self._pending[channel] = (job, fut)
            self._cond.notify()
        return fut

    def _run(self) -> None:
        one_openmp_thread()
        while True:
            with self._cond:
                while not self._pending and not self._closed:
                    self._cond.wait()
                if self._closed:
                    for _, fut in self._pending.values():
                        fut.set_exception(Closed("the editor is shutting down"))
                    self._pending.clear()
                    return
                _, (job, fut) = self._pending.popitem(last=False)
            if not fut.set_running_or_notify_cancel():
                continue
            self._running = fut
            try:
                value = job(self.engine)
            except BaseException as exc:  # noqa: BLE001 - handed to the waiting request
                _settle(fut, exc=exc)
                if self.on_error is not None and not self._closed:
                    try:
                        self.on_error(exc)
                    except Exception as exc2:  # noqa: BLE001
                        log.warning("editor: recovery after an error failed: %s: %s", type(exc2).__name__, exc2)
            else:
                _settle(fut, value=value)
            finally:
                self._running = None

    @property
    def busy(self) -> bool:
        """A job is still running on the solver thread."""
        return self._thread.is_alive() and self._running is not None

    def abandon(self) -> None:
        """Shutting down: fail the waiting jobs and the running one with Closed at once.

        The running job goes on on its (daemon) thread, but nobody waits for it:
        a server shutdown (Ctrl-C, SIGTERM) does not wait for a long solve.
        """
        with self._cond:
            self._closed = True
            for _, fut in self._pending.values():
                _settle(fut, exc=Closed("the editor is shutting down"))
            self._pending.clear()
            running = self._running
            self._cond.notify()
        if running is not None:
            _settle(running, exc=Closed("the editor is shutting down"))

    def close(self, timeout: float | None = 30.0) -> bool:
        """Stop after the running job (waiting ones fail with Closed); True if the thread has ended."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout)
        return not self._thread.is_alive()


def _settle(fut: Future, value=None, exc=None) -> None:
    """Set a future's outcome unless it has one already (abandon() may have failed it)."""
    try:
        if exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(value)
    except Exception:  # noqa: BLE001 - InvalidStateError: already settled
        pass

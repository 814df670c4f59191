"""One solver thread for the editor: jobs run one at a time, and a newer request replaces a waiting one.

A Session is not thread-safe, so every job (a function of the engine) runs
on this one thread. Requests come in *channels* (one per websocket
connection, one for the JSON API): a channel holds at most one waiting job,
and a new job replaces it; the replaced job's future fails with Superseded
(the page gets ``{"dropped": true}``, the API 409). So while the solver is
busy, a drag's intermediate positions are dropped, never queued: the next
solve is always for the newest one. Channels waiting together are served in
the order they started waiting.

What the process holds when the solver thread starts (the engine's first
model, the compiled forms, the libraries' objects: some 67k of them for
finger.toml) is moved out of the cyclic garbage collector's reach
(``gc.freeze``): a full collection walked them all, 36-105 ms, once in
every 80 or so frames of a drag, in the middle of a frame (with it frozen:
under 3 ms). What is made later is collected as usual, and whenever no
request has come for IDLE seconds the thread collects everything and
freezes what lives again (a re-mesh's new model, whose full collections
took up to 344 ms in a frame at 19k DOFs on a loaded host; the old model's
garbage goes then). The worker unfreezes all when it ends.

Every job has a budget (:class:`Budget`): seconds of the solver's time and
bytes it may add to the process's resident memory. A watchdog thread looks
at the running job every POLL seconds; one over budget is answered at once
with OverBudget (the client is told, JSON 503), and :class:`Cancel` is raised
inside the solver thread (``PyThreadState_SetAsyncExc``), again every
RAISE_AGAIN seconds while the job has not ended (a library callback may
swallow one). Python acts on it between two calls into C: a single call
(one factorisation, one meshing) is not cut short, and the DOF budget of
skelfem.editor.engine keeps those short. A cancelled job is treated as an
unexpected failure whatever it returned: ``on_error`` starts the solver again
from the last design that solved, and the requests waiting meanwhile are
served after it.
"""
from __future__ import annotations

import ctypes
import gc
import logging
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import Future
from dataclasses import dataclass

log = logging.getLogger("skelfem")

POLL = 0.05          # s between two looks of the watchdog at the running job
IDLE = 0.25          # s without a request after which the solver thread collects the garbage (module doc)
RAISE_AGAIN = 0.5    # s after which Cancel is raised again in a job that has not ended


@dataclass(frozen=True)
class Budget:
    """What one request may take of the solver: seconds of its time, bytes added to the resident memory."""

    seconds: float = 60.0
    memory: float = 4e9

    def __post_init__(self):
        if not (self.seconds > 0 and self.memory > 0):
            raise ValueError(f"a budget must be positive, got {self.seconds} s and {self.memory} bytes")


def resident_bytes() -> int:
    """This process's resident memory (bytes; 0 where /proc cannot be read)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _raise_in(thread_id: int, exc_type) -> None:
    """Raise exc_type in the thread thread_id at its next Python instruction (None: take back one not raised yet)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id),
                                               ctypes.py_object(exc_type) if exc_type is not None else None)


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


def one_blas_thread() -> int:
    """Make every OpenBLAS loaded in this process run one thread; returns how many libraries were told.

    The editor's solves are small (a factorisation of a few thousand unknowns,
    2x2 inverses per cell for the page's fields): OpenBLAS's threads only wait
    for each other there, and on a busy host they spin while the frame waits
    (np.linalg.inv of finger.toml's 1,356 cells: 58 ms with two threads on a
    loaded host, 1.2 ms with one). The count is process-wide, and the editor's
    process only serves the editor.
    """
    told = 0
    for path in loaded_libraries("blas"):
        try:
            set_threads = ctypes.CDLL(path).openblas_set_num_threads
        except (OSError, AttributeError):
            continue
        set_threads(1)
        told += 1
    return told


def loaded_libraries(word: str) -> list[str]:
    """Paths of the shared libraries mapped into this process whose file name contains word."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            paths = {line.split(None, 5)[-1].strip() for line in f if ".so" in line}
    except OSError:
        return []
    return sorted(p for p in paths if p.startswith("/") and word in os.path.basename(p))


class Superseded(Exception):
    """A newer request of the same channel replaced this one before it ran."""


class Closed(Exception):
    """The worker has stopped."""


class OverBudget(Exception):
    """The job ran beyond its budget and was cancelled; the message says which budget and how to go on."""


class Cancel(BaseException):
    """Raised inside the solver thread to stop a job over budget (a BaseException: no ``except Exception``
    on the way swallows it)."""


class _Running:
    """The job on the solver thread, as the watchdog sees it."""

    def __init__(self, fut: Future):
        self.fut, self.t0, self.rss0 = fut, time.monotonic(), resident_bytes()
        self.in_job = True               # Cancel may be raised in the solver thread only while this holds
        self.over: str | None = None     # why it was cancelled
        self.raised = 0.0                # when Cancel was last raised


class Worker:
    """Runs ``job(engine)`` on its own thread, latest-wins per channel, each job within budget."""

    def __init__(self, engine, on_error=None, budget: Budget | None = None):
        self.engine = engine
        self.on_error = on_error              # called on the thread after a job raised an unexpected error
        self.budget = budget or Budget()
        self._pending: OrderedDict = OrderedDict()
        self._cond = threading.Condition()
        self._closed = False
        self._running: _Running | None = None   # the job being run, if any
        self.dropped = 0                      # jobs replaced before they ran
        self.cancelled = 0                    # jobs cancelled over budget
        self.tidying = False                  # the solver thread is collecting the garbage between requests
        self.tidied = 0                       # ... and has done so this often
        self._thread = threading.Thread(target=self._run, name="skelfem-solver", daemon=True)
        self._thread.start()
        self._watchdog = threading.Thread(target=self._watch, name="skelfem-budget", daemon=True)
        self._watchdog.start()

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
            self._cond.notify_all()
        return fut

    def _run(self) -> None:
        one_openmp_thread()
        one_blas_thread()
        gc.collect()                # what is garbage now goes; what lives is frozen (see the module doc)
        gc.freeze()
        try:
            self._serve()
        finally:
            gc.unfreeze()           # a closed editor's objects can be collected again

    def _serve(self) -> None:
        untidy = False                  # jobs ran since the garbage was last tidied
        while True:
            with self._cond:
                idle = not self._cond.wait_for(lambda: bool(self._pending) or self._closed,
                                               timeout=IDLE if untidy else None)
            if idle:                    # no request for IDLE seconds: tidy the garbage now, not in a frame
                self.tidying = True
                try:
                    gc.unfreeze()
                    gc.collect()
                    gc.freeze()
                finally:
                    self.tidying = False
                self.tidied += 1
                untidy = False
                continue
            untidy = True
            with self._cond:
                if self._closed:
                    for _, fut in self._pending.values():
                        _settle(fut, exc=Closed("the editor is shutting down"))
                    self._pending.clear()
                    return
                _, (job, fut) = self._pending.popitem(last=False)
                if not fut.set_running_or_notify_cancel():
                    continue
                running = self._running = _Running(fut)
                self._cond.notify_all()                 # the watchdog starts timing it
            value, exc = self._call(job)
            over = running.over
            if over is not None:                        # whatever it returned: its state is not to be trusted
                value, exc = None, Cancel(over)
            if exc is not None:
                _settle(fut, exc=exc)
                if self.on_error is not None and not self._closed:
                    try:
                        self.on_error(exc)
                    except Exception as exc2:  # noqa: BLE001
                        log.warning("editor: recovery after an error failed: %s: %s", type(exc2).__name__, exc2)
            else:
                _settle(fut, value=value)
            with self._cond:
                self._running = None

    def _call(self, job):
        """(value, None) or (None, the exception) of job(engine); no Cancel gets past its end."""
        try:
            try:
                value, exc = job(self.engine), None
            except BaseException as e:  # noqa: BLE001 - handed to the waiting request
                value, exc = None, e
        except Cancel as e:             # raised between the job's end and the line above
            value, exc = None, e
        while True:
            try:
                self._leave()
                return value, exc
            except Cancel as e:         # raised before _leave took it back
                value, exc = None, e

    def _leave(self) -> None:
        """The job has ended: the watchdog raises nothing more here, and a Cancel not raised yet is taken back."""
        with self._cond:
            if self._running is not None:
                self._running.in_job = False
            _raise_in(threading.get_ident(), None)

    def _watch(self) -> None:
        """The watchdog: cancel the running job once it is over its time or memory budget."""
        while True:
            with self._cond:
                while self._running is None and not self._closed:
                    self._cond.wait()
                if self._closed and self._running is None:
                    return
                self._check(self._running)
            time.sleep(POLL)

    def _check(self, run: _Running) -> None:
        """(with the lock held) Fail and cancel run if it is over budget; raise Cancel again if it goes on."""
        if not run.in_job:
            return
        now = time.monotonic()
        if run.over is None:
            b = self.budget
            grown = resident_bytes() - run.rss0
            if now - run.t0 > b.seconds:
                run.over = (f"the request took more than the editor's budget of {b.seconds:g} s a request "
                            "(skelfem edit --max-seconds)")
            elif grown > b.memory:
                run.over = (f"the request needed more than the editor's budget of {b.memory / 1e6:,.0f} MB of "
                            "memory a request (skelfem edit --max-memory)")
            else:
                return
            self.cancelled += 1
            log.warning("editor: %s; it is cancelled and the solver starts again from the last design that "
                        "solved", run.over)
            _settle(run.fut, exc=OverBudget(f"{run.over}; it was cancelled, and the solver starts again from the "
                                            "last design that solved; a larger mesh.size solves faster, and "
                                            "skelfem simulate has no such limit"))
        if now - run.raised >= RAISE_AGAIN:
            run.raised = now
            _raise_in(self._thread.ident, Cancel)

    @property
    def busy(self) -> bool:
        """A job is still running on the solver thread."""
        return self._thread.is_alive() and self._running is not None

    def abandon(self) -> None:
        """Shutting down: fail the waiting jobs and the running one with Closed at once, and cancel it.

        A server shutdown (Ctrl-C, SIGTERM) does not wait for a long solve: the
        running job is stopped at its next Python instruction, or, inside a long
        call into C, goes on on its (daemon) thread with nobody waiting for it.
        """
        with self._cond:
            self._closed = True
            for _, fut in self._pending.values():
                _settle(fut, exc=Closed("the editor is shutting down"))
            self._pending.clear()
            running = self._running
            if running is not None and running.in_job:
                _settle(running.fut, exc=Closed("the editor is shutting down"))
                if running.over is None:
                    running.over = "the editor is shutting down"
                running.raised = time.monotonic()
                _raise_in(self._thread.ident, Cancel)
            self._cond.notify_all()

    def close(self, timeout: float | None = 30.0) -> bool:
        """Stop after the running job (waiting ones fail with Closed); True if the thread has ended."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
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

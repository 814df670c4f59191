"""SIGINT and SIGTERM become an exception, so every run cleans up and says one line.

:func:`install` (called by the CLI) makes both signals raise
:class:`Interrupted`, a KeyboardInterrupt, wherever Python is; the output
folder's staging area is removed on the way out and ``skelfem`` prints
``error: interrupted`` and exits 128 + the signal (130, 143). Importing gmsh
resets SIGINT to the default (kill at once), so :func:`reinstall` is called
after every Gmsh import or initialisation. Inside :func:`critical` (the
rename that publishes a result) a signal is held back until the block ends.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """A SIGINT or SIGTERM arrived; code is the exit status (128 + signal number)."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted by signal {signum}")
        self.signum = signum
        self.code = 128 + signum


_installed = False
_critical = 0
_pending: int | None = None
_finished = False          # the command's one result is published (finish): later signals are dropped


_received: int | None = None


def _handler(signum, frame):
    global _pending, _received
    if _finished:
        return
    _received = signum
    if _critical:
        _pending = signum
        return
    raise Interrupted(signum)


def received() -> int | None:
    """The last signal the handlers caught (an Interrupted raised inside a C extension's import, say,
    can surface as another exception; this tells what really happened)."""
    return _received


def _unraisable(info) -> None:
    """An Interrupted raised where Python cannot raise (a finalizer, a weakref callback) is not lost:
    the signal is sent again a moment later, from a timer thread, so the handler raises at an
    ordinary point of the main thread once the callback is over; nothing is printed."""
    if isinstance(info.exc_value, Interrupted):
        timer = threading.Timer(0.005, os.kill, (os.getpid(), info.exc_value.signum))
        timer.daemon = True
        timer.start()
        return
    sys.__unraisablehook__(info)


def install() -> None:
    """Make SIGINT and SIGTERM raise Interrupted (main thread only; a no-op elsewhere)."""
    global _installed, _received, _finished
    if not _installed:
        _received = None
        _finished = False
    if threading.current_thread() is not threading.main_thread():
        return
    for s in SIGNALS:
        signal.signal(s, _handler)
    sys.unraisablehook = _unraisable
    _installed = True


def reinstall() -> None:
    """Put the handlers back if install() was called (after something reset them).

    Always set again: a C library (gmsh) resets the OS-level action behind
    Python's back, and signal.getsignal still reports our handler then.
    """
    if _installed:
        install()


def ignore() -> None:
    """Hold SIGINT and SIGTERM off from now on (a finished command on its way out).

    Blocked, not just ignored: MPI's and PETSc's finalisation at exit put the
    default actions back, which would kill a process whose work is done.
    """
    global _installed
    if threading.current_thread() is threading.main_thread():
        signal.pthread_sigmask(signal.SIG_BLOCK, set(SIGNALS))
        for s in SIGNALS:
            signal.signal(s, signal.SIG_IGN)
    _installed = False


@contextmanager
def held():
    """Block SIGINT/SIGTERM at the OS level for the block (e.g. an import that resets handlers),
    then put our handlers back and let a signal that came meanwhile through."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(SIGNALS))
    try:
        yield
    finally:
        reinstall()
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def uninstall() -> None:
    global _installed
    if _installed and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        sys.unraisablehook = sys.__unraisablehook__
    _installed = False


_abandoned: str | None = None     # a call interruptible() left running in its worker thread


def interruptible(fn, *args, what: str = "Gmsh", **kwargs):
    """fn(*args, **kwargs) in a worker thread while the main thread waits, so that SIGINT/SIGTERM (and
    Ctrl-C without our handlers) stop the caller within a fraction of a second.

    For long calls into a C library that releases the GIL and never returns to Python (Gmsh's mesher
    and OpenCASCADE's booleans): a signal is only acted upon when the main thread runs Python, and
    inside such a call it never does. The interrupted call cannot be stopped; it is left to run in its
    (daemon) thread, and the library must not be used again in this process (``abandoned``: the
    command line then leaves with os._exit once it has cleaned up). Off the main thread, fn is
    simply called.
    """
    global _abandoned
    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)
    box: dict = {}

    def work():
        try:
            box["value"] = fn(*args, **kwargs)
        except BaseException as exc:          # handed to the caller below
            box["error"] = exc
    worker = threading.Thread(target=work, name=f"skelfem-{what}", daemon=True)
    worker.start()
    try:
        while worker.is_alive():
            worker.join(0.05)
    except BaseException:
        _abandoned = what
        raise
    if "error" in box:
        raise box["error"]
    return box.get("value")


def abandoned() -> str | None:
    """The library an interrupted call was left running in (Gmsh), or None."""
    return _abandoned


def finish() -> None:
    """The command's one result is published: SIGINT/SIGTERM from now on are dropped (one held back
    by critical too), so the run ends as it would have, exit 0, and never reports an interruption
    beside a complete result it has just published."""
    global _finished, _pending
    _finished = True
    _pending = None


@contextmanager
def critical():
    """Hold SIGINT/SIGTERM back for the duration of the block, then raise if one came."""
    global _critical, _pending
    _critical += 1
    try:
        yield
    finally:
        _critical -= 1
        if not _critical and _pending is not None:
            signum, _pending = _pending, None
            raise Interrupted(signum)


_import_lock = threading.Lock()


def import_gmsh():
    """The gmsh module, imported from any thread (every import of gmsh in skelfem goes through here).

    gmsh.py calls signal.signal(SIGINT, SIG_DFL) at import, which Python refuses off the main thread
    (ValueError): a plan or a mesh made in a worker thread (a notebook's, an editor's) failed there.
    On the main thread the import runs with the signals held (see :func:`held`); off it, signal.signal
    answers None without touching anything for the calls made from that thread during the import (the
    main thread's go through), so gmsh keeps no old handler to restore at finalize and the process's
    handlers stay as they are.
    """
    if "gmsh" in sys.modules:               # imported (or being imported: the import waits for it)
        import gmsh
        return gmsh
    if threading.current_thread() is threading.main_thread():
        with held():
            import gmsh
        return gmsh
    with _import_lock:
        real = signal.signal
        me = threading.get_ident()

        def quiet(signalnum, handler):
            return None if threading.get_ident() == me else real(signalnum, handler)
        signal.signal = quiet                   # type: ignore[assignment]
        try:
            import gmsh
        finally:
            signal.signal = real                # type: ignore[assignment]
    return gmsh

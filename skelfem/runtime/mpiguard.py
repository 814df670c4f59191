"""Ending every MPI rank together, whatever went wrong on one of them.

A rank that fails while the others wait in a collective (a gather, a
factorisation, MPI_Finalize) would leave them waiting forever. So at the
end of a command (and of each sweep case) every rank calls :func:`agree` on
a communicator kept for this alone (a ``Dup``, so it never matches the
work's own collectives):

- a rank that finished normally enters a non-blocking barrier and waits;
- a rank that raised enters it too but waits at most ``GRACE`` seconds: if
  every rank arrives (they all failed the same way, or the others finished),
  the outcomes are exchanged and each rank returns the same exit status and
  message; if not, some rank is stuck in a collective that will never
  complete, so this rank prints its one ``error:`` line and calls
  ``MPI_Abort``, which ends every rank at once (mpirun then exits with this
  status, after Open MPI's own notice).

Failures that every rank meets in step (bad input, an unusable output
folder, a failed solve) therefore end cleanly with one message; only a
fault on one rank alone uses the abort.
"""
from __future__ import annotations

import os
import signal
import sys
import time

GRACE = 10.0        # seconds a failed rank waits for the others before aborting


def world_size_hint() -> int:
    """The MPI world size from the launcher's environment, without initialising MPI."""
    for var in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS"):
        v = os.environ.get(var)
        if v and v.isdigit():
            return int(v)
    return 1


def finalise_alone() -> None:
    """Finalise MPI before a process alone (no mpirun: no other rank waits for it) leaves with os._exit,
    so Open MPI removes its session folder from TMPDIR (an interrupt during start-up or inside a Gmsh
    call left ``ompi.HOST.UID/jf.N`` behind). Nothing under mpirun, or when MPI never started."""
    from . import interrupts
    mpi = sys.modules.get("mpi4py.MPI")         # imported (and MPI initialised) by then, or not at all
    if mpi is None or world_size_hint() != 1 or not mpi.Is_initialized() or mpi.Is_finalized():
        return
    try:
        with interrupts.held():
            mpi.Finalize()
    except Exception:  # noqa: BLE001 - leaving anyway
        pass


def rank_hint() -> int:
    for var in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK"):
        v = os.environ.get(var)
        if v and v.isdigit():
            return int(v)
    return 0


def control(comm):
    """A communicator for agree() on the ranks of comm (collective: call it where all ranks are)."""
    return comm.Dup() if comm.size > 1 else None


def agree(ctl, code: int, message: str | None, in_step: bool, grace: float = GRACE,
          say=None) -> tuple[int, str | None]:
    """The common outcome (exit status, message) of every rank of ctl; see the module doc.

    in_step: this rank returned normally (so it is where every rank will be).
    say(message) prints the one error line (used before an abort).
    """
    if ctl is None:
        return code, message
    from mpi4py import MPI

    old: list | None = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]
    try:                              # the run is over: a late signal must not interrupt the hand-shake
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_IGN)
    except ValueError:                # not the main thread
        old = None
    try:
        req = ctl.Ibarrier()
        if in_step:
            req.Wait()
        else:
            deadline = time.monotonic() + grace
            while not req.Test():
                if time.monotonic() > deadline:
                    if say is not None and message:
                        say(message)
                    sys.stderr.flush()
                    sys.stdout.flush()
                    MPI.COMM_WORLD.Abort(code or 3)
                time.sleep(0.005)
        outcomes = ctl.allgather((code, message))
    finally:
        if old is not None:
            for s, h in zip((signal.SIGINT, signal.SIGTERM), old):
                signal.signal(s, h)
    for c, m in outcomes:
        if c:
            return c, m
    return 0, None

"""The skelfem command (``skelfem.cli.main.main``) and its sub-commands, one module each.

Importing this package is the command-line entry point's start-up, and the
only place in skelfem that changes process state on import: PETSc gets no
signal handlers of its own and SIGINT/SIGTERM become a clean ``Interrupted``
(skelfem.runtime.interrupts), as early as possible, so a Ctrl-C during
start-up is clean too. The library (``import skelfem``) does none of this.
"""
import os as _os

# No PETSc signal handlers: PetscFinalize would put the default actions back while a finished
# command exits, and a SIGTERM then would kill it (status -15) after its result is complete.
_os.environ["PETSC_OPTIONS"] = (_os.environ.get("PETSC_OPTIONS", "") + " -no_signal_handler").strip()
from ..runtime import interrupts as _interrupts  # noqa: E402

_interrupts.install()


def _start_up() -> None:
    """Import the command line (DOLFINx, matplotlib and MPI_Init among it): a signal meanwhile ends the
    process with one ``error: interrupted`` line and 130 / 143, never a traceback. Gmsh is imported
    first with the signals blocked: its import sets SIGINT's default action, and DOLFINx imports it
    on the way, which let a Ctrl-C half a second into a run kill the process outright (status -2).
    A signal that came meanwhile is let through after it."""
    import sys
    try:
        with _interrupts.held():
            try:
                _interrupts.import_gmsh()
            except ImportError:
                pass
            from mpi4py import MPI  # noqa: F401
        from . import main  # noqa: F401
    except _interrupts.Interrupted as exc:
        sys.stdout.flush()
        sys.stderr.write("error: interrupted\n")
        sys.stderr.flush()
        from ..runtime.mpiguard import finalise_alone
        finalise_alone()
        _os._exit(exc.code)


_start_up()

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

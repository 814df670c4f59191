"""``python -m skelfem ...`` runs the skelfem command (e.g. under mpirun)."""
import sys

from skelfem.cli import main

sys.exit(main())

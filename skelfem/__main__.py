"""``python -m skelfem ...`` runs the skelfem command (e.g. under mpirun)."""
import sys

from .cli.main import main

sys.exit(main())

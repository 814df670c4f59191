"""Gmsh from a thread that is not the main one (skelfem.runtime.interrupts.import_gmsh).

gmsh.py calls signal.signal at import, which Python refuses off the main thread: a fabrication plan or
a mesh made first in a worker thread failed with ValueError. Run in a fresh interpreter, where gmsh is
not imported yet (under pytest another test has imported it already on the main thread).
"""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import signal, sys, threading
from mpi4py import MPI
from skelfem.design.parse import load_design
import skelfem.fabricate as fab
from skelfem.mesh.geometry import mesh_design

handler = signal.getsignal(signal.SIGINT)
design = load_design("geometry/finger.toml", ["mesh.size=8"])
box = {}

def work():
    try:
        assert "gmsh" not in sys.modules
        box["mesh"] = mesh_design(design, MPI.COMM_SELF).mesh.topology.index_map(2).size_local
        box["plan"] = sorted(fab.plan(design).routes)
    except BaseException as exc:
        box["error"] = repr(exc)

thread = threading.Thread(target=work)
thread.start()
thread.join()
print(box)
assert "error" not in box, box
assert box["mesh"] > 0 and "flexor" in box["plan"], box
assert signal.getsignal(signal.SIGINT) is handler       # the main thread's handler is left alone
"""


def test_plan_and_mesh_in_a_worker_thread():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr

"""The bundled designs: they load, mesh, and the demo behaves as a finger should."""
from pathlib import Path

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import load_design
from skelfem.mesh.geometry import mesh_design

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


def _solve(name, *overrides):
    session = Session(GEOMETRY / f"{name}.toml", overrides)
    return session, session.solve()


@pytest.mark.parametrize("name", ["finger", "finger_bones", "finger_soft", "finger4"])
def test_bundled_design_meshes_with_named_regions(name):
    design = load_design(GEOMETRY / f"{name}.toml")
    tm = mesh_design(design)
    assert set(tm.tags) == {"body"} | {f"bone:{b.name}" for b in design.bones}
    for tag in tm.tags.values():
        assert len(tm.cell_tags.find(tag)) > 0


def _orders(history):
    """Observed convergence orders log r_{k+1} / log r_k above the round-off floor."""
    r = np.asarray(history)
    pairs = [(a, b) for a, b in zip(r[:-1], r[1:]) if a < 0.5 and b > 1e-8]
    return [np.log(b) / np.log(a) for a, b in pairs]


def test_demo_converges_quadratically_and_curls_toward_the_tendon():
    session, result = _solve("finger")
    report = result.report
    assert report.converged and report.min_jacobian > 0
    orders = _orders(report.residual_history[-1])
    # the best of the last two steps: one of them may start near the round-off floor (1e-4 -> 4e-7 -> 3e-9)
    assert orders and max(orders[-2:]) > 1.8, report.residual_history[-1]
    tip = np.asarray(result.markers["tip"]["displacement"])
    assert tip[0] < -20.0          # the flexor runs at x = 3 < 10: the finger curls to -x
    model = session.model
    u = model.u.x.array
    tendon = model.term("cables", "flexor")
    assert tendon.cable.tension(u, tendon.rest_length) > 0
    assert result.cables["flexor"]["tension"] == tendon.cable.tension(u, tendon.rest_length)
    cables = [t.cable for t in model.terms_in("cables")]
    palmar = [c for c in cables if c.name.endswith("palmar")]
    dorsal = [c for c in cables if c.name.endswith("dorsal")]
    assert palmar and dorsal
    assert all(c.length(u) < c.L0 for c in palmar)       # the curl compresses the palmar side
    assert all(c.length(u) > c.L0 for c in dorsal)       # and stretches the dorsal ligaments


@pytest.mark.parametrize("E_bone", [0.1, 10.0, 1e3, 1e4])
def test_demo_converges_for_bone_to_silicone_stiffness_ratios(E_bone):
    """E_bone / E_silicone = 1 ... 1e5 on a coarse mesh."""
    _, result = _solve("finger", f"materials.pla.E={E_bone}", "mesh.size=3")
    assert result.converged, result.status
    assert result.min_jacobian > 0


def test_meshing_is_the_same_in_every_process():
    """Gmsh runs in a worker thread (interruptible); with its OpenMP default it then numbered the same mesh
    differently from one process to the next (and the answers moved by 1e-4 mm). One thread: the same
    mesh every time."""
    import subprocess
    import sys
    script = ("import hashlib, numpy as np\n"
              "from skelfem.design.parse import load_design\n"
              "from skelfem.mesh.geometry import mesh_design\n"
              f"tm = mesh_design(load_design({str(GEOMETRY / 'finger.toml')!r}, ['mesh.size=4']))\n"
              "print(hashlib.md5(np.round(tm.mesh.geometry.x, 12).tobytes()).hexdigest())\n")
    runs = {subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                           check=True).stdout for _ in range(4)}
    assert len(runs) == 1, runs

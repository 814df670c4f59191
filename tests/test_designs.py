"""The bundled designs: they load, mesh, and the demo behaves as a finger should."""
from pathlib import Path

import numpy as np
import pytest

from skelfem.design import load_design
from skelfem.geometry import mesh_design
from skelfem.scene import Scene
from skelfem.solver import NewtonSolver

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


def _solve(name, *overrides):
    design = load_design(GEOMETRY / f"{name}.toml", overrides)
    scene = Scene(design, mesh_design(design))
    return scene, NewtonSolver(scene, design.solver).solve(design.solver.steps)


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
    scene, report = _solve("finger")
    assert report.converged and report.min_jacobian > 0
    orders = _orders(report.residual_history[-1])
    assert orders and orders[-1] > 1.8, report.residual_history[-1]
    tip = scene.marker_positions()[0] - scene.marker_X[0]
    assert tip[0] < -20.0          # the flexor runs at x = 3 < 10: the finger curls to -x
    u = scene.u.x.array
    tendon = scene.cables[0]
    assert tendon.tension(u, scene.rest_lengths()[0]) > 0
    palmar = [c for c in scene.cables if c.name.endswith("palmar")]
    dorsal = [c for c in scene.cables if c.name.endswith("dorsal")]
    assert all(c.length(u) < c.L0 for c in palmar)       # the curl compresses the palmar side
    assert all(c.length(u) > c.L0 for c in dorsal)       # and stretches the dorsal ligaments


@pytest.mark.parametrize("E_bone", [0.1, 10.0, 1e3, 1e4])
def test_demo_converges_for_bone_to_silicone_stiffness_ratios(E_bone):
    """E_bone / E_silicone = 1 ... 1e5 on a coarse mesh."""
    scene, report = _solve("finger", f"materials.pla.E={E_bone}", "mesh.size=3")
    assert report.converged, report.status
    assert report.min_jacobian > 0

"""The live Session: the same answers as the CLI, live parameters, edits, errors, serial = MPI."""
import json
import sys

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import DesignError

from conftest import GEOMETRY

FINGER = GEOMETRY / "finger.toml"


def _close(a, b, rel=1e-8):
    """Nested dicts / lists of numbers equal to a relative tolerance (scaled by the largest entry)."""
    if isinstance(a, dict):
        assert set(a) == set(b)
        for k in a:
            _close(a[k], b[k], rel)
    elif isinstance(a, (list, tuple)):
        a, b = np.asarray(a, float), np.asarray(b, float)
        assert np.allclose(a, b, rtol=rel, atol=rel * max(1.0, np.abs(b).max(initial=0.0)))
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=rel, abs=rel)
    else:
        assert a == b


READOUTS = ("energy", "markers", "cables", "pins", "grounds", "min_jacobian", "dofs", "cells")


@pytest.mark.mpi
def test_session_equals_simulate_with_set(tmp_path, mpirun):
    sets = ["cables.flexor.contraction=6.5", "materials.pla.E=800", "mesh.size=2.5"]
    args = [mpirun.skelfem, "simulate", FINGER, "--out", tmp_path, "--no-picture", "-q"]
    for s in sets:
        args += ["--set", s]
    p = mpirun.run(args)
    assert p.returncode == 0, p.stderr
    cli = json.loads((tmp_path / "result.json").read_text())
    with Session(FINGER, sets) as s:
        r = s.solve().to_dict()
    for key in READOUTS:
        _close(r[key], cli[key])


def test_set_is_live_warm_and_equals_a_fresh_solve():
    with Session(FINGER, ["mesh.size=3"]) as s:
        s.solve()
        mesh, A = s.model.mesh, s.solver.A
        s.set({"cables.flexor.contraction": 7.0, "materials.pla.E": 2000.0})
        r = s.solve()
        assert s.model.mesh is mesh and s.solver.A is A          # no re-mesh, no new matrix
        assert r.converged and r.attempts[0].get("warm")
        assert r.cables["flexor"]["contraction"] == 7.0
    with Session(FINGER, ["mesh.size=3", "cables.flexor.contraction=7", "materials.pla.E=2000"]) as fresh:
        ref = fresh.solve()
    _close(r.markers, ref.markers, rel=1e-6)


def test_set_of_a_geometric_key_remeshes():
    with Session(FINGER, ["mesh.size=4"]) as s:
        s.solve()
        dofs = s.dofs
        s.set({"mesh.size": 3.0})
        r = s.solve()
        assert s.dofs > dofs and r.converged


def test_edit_carries_the_solution_over():
    with Session(FINGER, ["mesh.size=3"]) as s:
        cold = s.solve()
        d = s.design.raw
        d["bones"][0]["outline"][0][0] += 0.5
        s.edit(d)
        r = s.solve()
    assert r.converged and r.newton_iterations < cold.newton_iterations


def test_a_re_meshing_edit_frees_the_old_solver_before_it_builds_the_new_model(monkeypatch):
    """The old Newton matrix and its multigrid or factorisation beside the new model were the peak of a 3D
    ladder's last level; the old model stays until the solution is carried over."""
    from skelfem.fem.model import Model
    with Session(FINGER, ["mesh.size=4"]) as s:
        s.solve()
        old, build = s.solver, Model.__init__
        old_matrix_alive = []

        def spy(self, *args, **kwargs):
            old_matrix_alive.append(old.A.handle != 0)
            build(self, *args, **kwargs)
        monkeypatch.setattr(Model, "__init__", spy)
        d = s.design.raw
        d["bones"][0]["outline"][0][0] += 0.5
        assert s.edit(d) == "re-meshed"
        r = s.solve()
    assert old_matrix_alive == [False] and r.converged and r.newton_iterations <= 4


def test_the_carried_over_solution_does_not_depend_on_the_chunk_size(monkeypatch):
    """An edit locates the new nodes in the old mesh CARRY_CHUNK at a time: chunks of 7 nodes and one
    chunk of all give the same start on the new mesh."""
    import skelfem.session as session
    starts = []
    for chunk in (7, 10**9):
        monkeypatch.setattr(session, "CARRY_CHUNK", chunk)
        with Session(FINGER, ["mesh.size=3"]) as s:
            s.solve()
            d = s.design.raw
            d["bones"][0]["outline"][0][0] += 0.5
            s.edit(d)
            starts.append(s.model.u.x.array.copy())
    assert len(starts[0]) > 100 * 7 and np.abs(starts[0]).max() > 0.1
    assert np.array_equal(starts[0], starts[1])


@pytest.mark.parametrize("delta", [1.0, -1.0])
def test_warm_set_takes_the_euler_predictor_and_few_newton_iterations(delta):
    """A 1 mm contraction change either way: the predictor du/dp dp, then <= 5 Newton iterations.

    Releasing the tendon leaves it momentarily slack at the old equilibrium; a
    Newton step there (no cable stiffness) overshoots, which took 12 iterations
    before the predictor. The answer equals a cold solve of the changed design.
    """
    with Session(FINGER) as s:
        s.solve()
        u0 = s.design.cable("flexor").contraction
        s.set({"cables.flexor.contraction": u0 + delta})
        r = s.solve()
        assert r.converged and r.attempts[0]["predictor_step"] > 0.0
        assert r.newton_iterations <= 5, r.report.residual_history
        assert not s.model.changes                          # consumed by the solve
    with Session(FINGER, [f"cables.flexor.contraction={u0 + delta}"]) as fresh:
        ref = fresh.solve()
    _close(r.markers, ref.markers, rel=1e-7)


def test_predictor_follows_vector_parameters_and_repeated_sets(strip_design):
    """Pin moves and loads (vectors) move along old + s (new - old); two sets before one solve add up."""
    d = strip_design(size=3.0, contraction=0.5)
    d["loads"] = [{"name": "push", "at": [5.0, 60.0], "force": [0.0, 0.0]}]
    with Session(d) as s:
        s.solve()
        s.set({"loads.push.force": [0.02, 0.0]})
        s.set({"loads.push.force": [0.05, -0.01], "pins.base.move": [0.5, 0.0]})
        (old, new), = [s.model.changes["loads.push.force"]]
        assert np.allclose(old, 0.0) and np.allclose(new, [0.05, -0.01])
        r = s.solve()
        assert r.converged and r.attempts[0]["predictor_step"] > 0.0
    changed = dict(d, loads=[{"name": "push", "at": [5.0, 60.0], "force": [0.05, -0.01]}])
    changed["pins"] = [dict(d["pins"][0], move=[0.5, 0.0])]
    with Session(changed) as fresh:
        ref = fresh.solve()
    _close(r.markers, ref.markers, rel=1e-7)


def test_carry_over_makes_free_bones_rigid(strip_design):
    """Elasticity.carry_over: a bone's start motion becomes the rigid motion that fits it best."""
    with Session(strip_design(size=3.0, bones=True)) as s:
        term = s.model.term("materials")
        rng = np.random.default_rng(1)
        u = rng.normal(scale=0.3, size=s.model.n_local)
        term.carry_over(u)
        groups = term._bone_groups()
        assert len(groups) == 2
        for dofs, X in groups:
            y = X + u[dofs]
            dX = np.linalg.norm(X[:, None] - X[None], axis=2)
            dy = np.linalg.norm(y[:, None] - y[None], axis=2)
            assert np.allclose(dX, dy, atol=1e-10)          # distances kept: a rigid motion
        v = u.copy()
        term.carry_over(v)
        assert np.allclose(u, v, atol=1e-12)               # a rigid motion stays as it is


def test_untangle_smooths_an_inverted_start_only_where_it_is_inverted(strip_design):
    """Model.untangle: a start state with one inverted cell (a node pushed across its cell) becomes
    admissible in a few sweeps; nodes away from that cell keep their displacement; an admissible state is
    left as it is (0 sweeps)."""
    with Session(strip_design(size=3.0)) as s:
        s.solve()
        m = s.model
        assert m.untangle(m.u.vector) == 0
        nodes = m.V.dofmap.list.array.reshape(m.num_cells, -1)
        X = m.V.tabulate_dof_coordinates()[:, :2]
        c = int(np.argmin(np.linalg.norm(X[nodes].mean(axis=1) - [5.0, 30.0], axis=1)))   # an inner cell
        u = m.u.x.array.reshape(-1, 2)
        before = u.copy()
        corners = X[nodes[c, :3]]
        u[nodes[c, 0]] += 2.0 * (corners[1:].mean(axis=0) - corners[0])        # across the opposite edge
        assert m.min_jacobian(m.u.vector) <= 0.0
        sweeps = m.untangle(m.u.vector)
        assert 1 <= sweeps < 20 and m.min_jacobian(m.u.vector) > 0.0
        moved = np.linalg.norm(m.u.x.array.reshape(-1, 2) - before, axis=1) > 1e-12
        far = np.linalg.norm(X - X[nodes[c, 0]], axis=1) > 6.0
        assert moved.any() and not moved[far].any()


@pytest.mark.parametrize("changes, key", [
    ({"cables.nope.contraction": 1.0}, "cables"),
    ({"materials.pla.E": -5.0}, "materials.pla.E"),
    ({"cables.flexor.contraction": "x"}, "cables.flexor.contraction"),
    ({"mesh.degree": 7}, "mesh.degree"),
])
def test_bad_set_raises_one_line_and_keeps_the_session(changes, key):
    with Session(FINGER, ["mesh.size=4"]) as s:
        r0 = s.solve()
        with pytest.raises(DesignError) as exc:
            s.set(changes)
        assert key in str(exc.value) and "\n" not in str(exc.value)
        r1 = s.solve()
    _close(r1.markers, r0.markers, rel=1e-7)


MPI_DESIGN = """
import json, sys
sys.path.insert(0, "tests")
from test_terms import _designs
from skelfem import Session
from mpi4py import MPI
with Session(_designs()["full"]) as s:
    r = s.solve().to_dict()
if MPI.COMM_WORLD.rank == 0:
    json.dump(r, open(sys.argv[1], "w"))
"""


@pytest.mark.mpi
@pytest.mark.slow
def test_every_term_serial_equals_mpirun_2(tmp_path, mpirun):
    """A design with every MPI-capable term (all but self-contact): read-outs agree over 1 and 2 ranks."""
    script = tmp_path / "run.py"
    script.write_text(MPI_DESIGN)
    out = {}
    for n in (1, 2):
        p = mpirun.run([sys.executable, script, tmp_path / f"r{n}.json"], ranks=n, timeout=240)
        assert p.returncode == 0, p.stderr[-2000:]
        out[n] = json.loads((tmp_path / f"r{n}.json").read_text())
    assert out[1]["converged"] and out[2]["converged"]
    for key in READOUTS + ("gravity", "tractions"):
        _close(out[2][key], out[1][key], rel=1e-7)

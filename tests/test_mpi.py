"""Domain decomposition: `mpirun -n 2` and serial runs agree, for every ingredient that couples ranks."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from _designs import toml_text

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.mpi, pytest.mark.slow]


def _simulate(mpirun, design, out, ranks, *sets):
    args = [mpirun.skelfem, "simulate", design, "--out", out, "-q", *sum((["--set", s] for s in sets), [])]
    res = mpirun.run(args, ranks)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads((out / "result.json").read_text())


def _close(a, b, rel=1e-6, scale=0.0):
    """|a - b| <= rel * max(|a|, scale): forces that vanish are compared on a force scale."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.linalg.norm(a - b) <= rel * max(np.linalg.norm(a), scale, 1e-12)


def _agree(serial, parallel):
    assert parallel["converged"] and parallel["dofs"] == serial["dofs"]
    assert parallel["newton_iterations"] == serial["newton_iterations"]
    for name, m in serial["markers"].items():
        assert _close(m["displacement"], parallel["markers"][name]["displacement"]), name
    for name, c in serial["cables"].items():
        assert _close([c["tension"]], [parallel["cables"][name]["tension"]]), name
        assert _close(c["tensions"], parallel["cables"][name]["tensions"]), name
        assert c["slipping"] == parallel["cables"][name]["slipping"], name
    force = max(c["tension"] for c in serial["cables"].values())
    for name, p in serial["pins"].items():
        assert _close(p["reaction"], parallel["pins"][name]["reaction"], 1e-6, force), name
    for name, g in serial["grounds"].items():
        assert _close(g["force"], parallel["grounds"][name]["force"], 1e-6, force), name


def test_arm3d_two_ranks_match_serial(tmp_path, mpirun, picture):
    serial = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "s", 1, "mesh.size=9")
    parallel = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "p", 2, "mesh.size=9")
    _agree(serial, parallel)
    import meshio
    m = meshio.read(tmp_path / "p" / "solution.xdmf")        # gathered to rank 0
    assert m.point_data["displacement"].shape[1] == 3
    assert {"tetra", "line"} <= {c.type for c in m.cells}
    picture(tmp_path / "p" / "deformed.png", 600, 600)


@pytest.mark.parametrize("rigid, degree", [(False, 1), (True, 1), (False, 2)], ids=["elastic", "rigid", "elastic-P2"])
def test_iterative_solves_agree_across_ranks(tmp_path, mpirun, rigid, degree):
    """[solver] linear = "iterative" on arm3d (four PLA bones, elastic or rigid: the border's unknowns
    on the first rank; taut tendons; at P2 two-level p-multigrid, its P1 interpolation distributed):
    2 ranks and serial reach the same equilibrium (multigrid aggregates differently per partition,
    so the Krylov and even the Newton iteration counts may differ; the answers must not)."""
    sets = ["mesh.size=9", "solver.linear=iterative", "solver.rtol=1e-11", f"mesh.degree={degree}"]
    if rigid:
        sets += [f"bones.{b}.rigid=true" for b in ("humerus", "radius", "ulna", "hand")]
    serial = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "s", 1, *sets)
    parallel = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "p", 2, *sets)
    assert serial["linear_solver"] == parallel["linear_solver"] == "iterative"
    assert parallel["converged"] and parallel["dofs"] == serial["dofs"]
    for name, m in serial["markers"].items():
        assert _close(m["position"], parallel["markers"][name]["position"], 1e-8), name
    force = max(c["tension"] for c in serial["cables"].values())
    assert force > 0
    for name, c in serial["cables"].items():
        assert _close([c["tension"]], [parallel["cables"][name]["tension"]], 1e-7, force), name


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_every_ingredient_agrees_across_ranks(tmp_path, mpirun, strip_design, friction):
    """Bones, tendon, pretensioned ligament, spring pin, moved pin, point load and a ground, P2; with and
    without cable friction."""
    d = strip_design(length=40.0, size=2.0, degree=2, contraction=0.4)
    d["bones"] = [{"name": "b", "outline": [[3, 10], [7, 10], [7, 25], [3, 25]], "material": "hard"}]
    d["cables"].append({"name": "lig", "kind": "ligament", "path": [[2, 5], [4, 20], [2, 35]],
                        "stiffness": 2.0, "pretension": 1.0})
    d["pins"][0]["move"] = [0.2, 0.0]
    d["pins"].append({"name": "side", "region": [[-1, 30], [0.5, 40]], "kind": "spring", "stiffness": 5.0})
    d["loads"] = [{"name": "push", "at": [5, 38], "force": [0.3, -0.02]}]
    d["grounds"] = [{"name": "wall", "point": [10.1, 0], "normal": [-1, 0], "stiffness": 10.0}]
    d["markers"]["mid"] = [5, 20]
    d["solver"] = {"steps": 2}
    for c in d["cables"]:
        c["friction"] = friction
    path = tmp_path / "all.toml"
    path.write_text(toml_text(d))
    serial = _simulate(mpirun, path, tmp_path / "s", 1)
    assert np.linalg.norm(serial["grounds"]["wall"]["force"]) > 0      # the ground is engaged
    assert all(c["tension"] > 0 for c in serial["cables"].values())    # both cables taut: low-rank parts
    if friction:
        assert any(np.ptp(c["tensions"]) > 1e-3 * c["tension"] for c in serial["cables"].values())
    _agree(serial, _simulate(mpirun, path, tmp_path / "p", 2))


def test_pull_study_under_mpirun_matches_serial(tmp_path, mpirun):
    """A study runs unchanged on a partitioned mesh (markers, loads, pins across ranks)."""
    study = [sys.executable, ROOT / "studies" / "pull_test.py", "--size", "3", "--loads", "2", "6"]
    for name, ranks in (("serial", 1), ("mpi", 2)):
        res = mpirun.run(study + ["--out", tmp_path / name], ranks)
        assert res.returncode == 0, res.stdout + res.stderr
    rows = [(tmp_path / n / "pull_test.csv").read_text().splitlines() for n in ("serial", "mpi")]
    assert len(rows[0]) == 7 and rows[0] == rows[1]


def _agree_contacts(serial, parallel, rel=1e-6):
    """Objects and contacts of two runs of one design agree (forces on the scale of the largest)."""
    assert parallel["converged"] and parallel["newton_iterations"] == serial["newton_iterations"]
    for name, o in serial.get("objects", {}).items():
        p = parallel["objects"][name]
        assert _close(o["position"], p["position"], rel), name
        a, b = np.atleast_1d(o["rotation"]), np.atleast_1d(p["rotation"])      # 3D: rotation vectors
        assert np.linalg.norm(a - b) <= 1e-9 + rel * np.linalg.norm(a), name
    assert [c["between"] for c in serial["contacts"]] == [c["between"] for c in parallel["contacts"]]
    scale = max(c.get("normal_magnitude", np.linalg.norm(c["normal_force"])) for c in serial["contacts"])
    for a, b in zip(serial["contacts"], parallel["contacts"]):
        for key in ("normal_force", "friction_force"):
            if key in a:
                assert _close(a[key], b[key], rel, scale), (a["between"], key)
        if "sticking" in a:
            assert abs(a["sticking"] - b["sticking"]) < 1e-6
    for name, m in serial["markers"].items():
        assert _close(m["position"], parallel["markers"][name]["position"], rel), name


@pytest.mark.parametrize("dim", [2, 3])
def test_self_contact_agrees_across_ranks(tmp_path, mpirun, dim):
    """2D: the knuckled finger curls until its notches close (the barrier active); 3D: a notched strip
    curled by its tendon until the notch closes (the barrier on the boundary's triangles). The same
    answer on 2 ranks, and the same per-node contact forces in solution.xdmf."""
    import meshio
    if dim == 2:
        path, sets, dhat = ROOT / "geometry" / "finger_knuckles.toml", ["mesh.size=3"], 0.3
    else:
        from test_contact_3d import DHAT, notched
        path, sets, dhat = tmp_path / "notched3d.toml", [], DHAT
        path.write_text(toml_text(notched()))
    serial = _simulate(mpirun, path, tmp_path / "s", 1, *sets)
    parallel = _simulate(mpirun, path, tmp_path / "p", 2, *sets)
    a, b = serial["contact"]["self"], parallel["contact"]["self"]
    assert 0 < a["min_distance"] < dhat and a["normal_magnitude"] > 0      # within dhat: in contact
    assert parallel["newton_iterations"] == serial["newton_iterations"]
    assert abs(b["min_distance"] - a["min_distance"]) < 1e-9
    assert _close([b["normal_magnitude"]], [a["normal_magnitude"]])
    assert _close(serial["markers"]["tip"]["position"], parallel["markers"]["tip"]["position"])
    forces = []
    for run in ("s", "p"):
        m = meshio.read(tmp_path / run / "solution.xdmf")
        order = np.lexsort(np.round(m.points, 9).T[::-1])
        forces.append(np.asarray(m.point_data["contact_normal_force"])[order])
    assert np.abs(forces[0] - forces[1]).max() <= 1e-6 * np.abs(forces[0]).max()


@pytest.mark.parametrize("case", ["two_fingers", "gripper", "ground", "elastic", "cube3d"])
def test_bodies_objects_and_their_friction_agree_across_ranks(tmp_path, mpirun, case):
    """Contact between bodies and objects (the IPC barrier on the whole boundary, gathered on every rank),
    friction between them and on a ground, an elastic object, a cube on a block in 3D: mpirun -n 2 gives
    the serial answer with the same Newton iterations."""
    from test_objects import G, _base, _box, _gel
    sets = []
    if case == "two_fingers":
        path, sets = ROOT / "geometry" / "two_fingers.toml", ["mesh.size=3"]
    elif case == "gripper":
        path = ROOT / "geometry" / "gripper.toml"
        sets = ["mesh.size=3", "cables.left_flexor.contraction=4", "cables.right_flexor.contraction=4"]
    else:
        if case == "ground":                      # a box held on a tilted floor by friction
            th = np.radians(20.0)
            d = _base([_box(20, 0, 26, 3)], gravity={"acceleration": [G * np.sin(th), -G * np.cos(th)]},
                      grounds=[{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0,
                                "friction": 0.5}], markers={"b": [23.0, 1.5]})
        elif case == "cube3d":                    # 3D: the contact's triangles, friction on them
            from test_objects_3d import _design
            d = _design([0.0, -G, 0.0])
            sets = ["mesh.size=2.5"]
        else:
            d = _gel(E=0.05)
        path = tmp_path / f"{case}.toml"
        path.write_text(toml_text(d))
    serial = _simulate(mpirun, path, tmp_path / "s", 1, *sets)
    assert serial["contacts"] and serial["converged"]
    _agree_contacts(serial, _simulate(mpirun, path, tmp_path / "p", 2, *sets))
    # solution.xdmf's contact fields: the same forces at the same nodes (matched by position)
    import meshio
    fields = []
    for run in ("s", "p"):
        m = meshio.read(tmp_path / run / "solution.xdmf")
        order = np.lexsort(np.round(m.points, 9).T[::-1])
        fields.append({k: np.asarray(m.point_data[k])[order] for k in ("contact_force", "contact_traction")})
    for key in ("contact_force", "contact_traction"):
        scale = np.abs(fields[0][key]).max()
        assert scale > 0 or case == "ground", key            # the box touches the floor only: no such force
        assert np.abs(fields[0][key] - fields[1][key]).max() <= 1e-6 * scale, key


def test_the_newton_matrix_is_made_without_reallocating_under_mpi(tmp_path, mpirun):
    """On 2 ranks the cables' curvature blocks (a segment couples the nodes of the two cells at its ends,
    which may lie on another rank) are preallocated with the element pattern: setting them reallocated
    rows 432 times on arm3d at 6 mm (14 s of set-up at 118k DOFs) before."""
    script = tmp_path / "mallocs.py"
    script.write_text(
        "from mpi4py import MPI\nfrom petsc4py import PETSc\nfrom skelfem import Session\n"
        f"with Session({str(ROOT / 'geometry' / 'arm3d.toml')!r}, overrides=['mesh.size=6']) as s:\n"
        "    info = s.solver.A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)\n"
        "    if MPI.COMM_WORLD.rank == 0:\n"
        "        print(int(info['mallocs']), int(info['nz_used']))\n")
    res = mpirun.run([sys.executable, script], 2)
    assert res.returncode == 0, res.stdout + res.stderr
    mallocs, nonzeros = map(int, res.stdout.split()[-2:])
    assert nonzeros > 0 and mallocs == 0

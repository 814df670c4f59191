"""Finite anchors: a cable end or bend in silicone acts on a disk, so refinement converges (a point force does not)."""
import numpy as np
import pytest

from skelfem import Session
from skelfem.design import DesignError, load_design, parse_design
from skelfem.terms.cables import anchor_samples, anchor_weights

from _designs import strip
from conftest import GEOMETRY

SOFT = GEOMETRY / "finger_soft.toml"
STRAIGHT = "cables.flexor.path=[[3,0],[3,84]]"       # no bend in the silicone: the end is the only point force


def _tip(size, radius):
    with Session(SOFT, [f"mesh.size={size}", STRAIGHT, f"cables.flexor.anchor_radius={radius}"]) as s:
        r = s.solve()
        assert r.converged
        return np.array(r.markers["tip"]["position"])


@pytest.mark.slow
def test_anchored_end_converges_under_refinement_where_a_point_end_does_not():
    sizes = (2.0, 1.0, 0.5)
    anchored = [_tip(h, 2.0) for h in sizes]               # h <= r from the second mesh on
    point = [_tip(h, 0.0) for h in sizes]
    da = [np.linalg.norm(b - a) for a, b in zip(anchored[:-1], anchored[1:])]
    dp = [np.linalg.norm(b - a) for a, b in zip(point[:-1], point[1:])]
    assert da[1] < 0.5 * da[0] and da[1] < 0.06            # the change falls with h (0.133, 0.049)
    assert dp[1] > 0.3 and dp[1] > da[1] * 5               # the point force's log singularity: 0.82 mm


def test_anchor_lattice_is_inside_the_disk_and_centred():
    c = np.array([3.0, 4.0])
    p = anchor_samples(c, 1.5)
    assert np.all(np.linalg.norm(p - c, axis=1) <= 1.5 + 1e-12)
    assert np.allclose(p.mean(axis=0), c) and len(p) > 40
    q = anchor_samples(np.zeros(3), 1.0)
    assert np.allclose(q.mean(axis=0), 0.0) and len(q) > 200


def test_anchor_weights_are_a_smooth_bump_whose_lattice_sum_is_the_disks_integral():
    c = np.array([3.0, 4.0])
    w = anchor_weights(np.array([c, c + [1.5, 0.0], c + [0.0, 3.0], c + [0.75, 0.0]]), c, 1.5)
    assert np.allclose(w, [1.0, 0.0, 0.0, 0.5625])          # (1 - rho^2)^2: 1 at the centre, 0 on and off the rim
    for n in (8, 16):                                        # integral of w over the disk = pi r^2 / 3
        p = anchor_samples(c, 1.5, n)
        h = 1.5 / n
        assert anchor_weights(p, c, 1.5).sum() * h * h == pytest.approx(np.pi * 1.5 ** 2 / 3, rel=2e-3)


def test_only_ends_and_bends_in_silicone_off_the_pinned_base_are_anchored():
    with Session(SOFT, ["mesh.size=3"]) as s:
        term = s.model.term("cables", "flexor")
        assert set(term.anchors) == {1, 2}                 # [3, 78], [9, 84] in silicone; [3, 0] on the base
        assert term.anchors[2] == pytest.approx(0.01 * np.hypot(20.0, 100.0), rel=1e-6)
        u = np.zeros(s.model.n_local)
        u[0::2], u[1::2] = 0.3, -0.2                        # a translation moves every via point alike
        X = term.cable.X
        assert np.allclose(term.cable.positions(u), X + [0.3, -0.2])
    with Session(GEOMETRY / "finger.toml", ["mesh.size=4"]) as s:
        anchored = {t.name: set(t.anchors) for t in s.model.terms_in("cables") if t.anchors}
        assert anchored == {"flexor": {1}}          # its bend at [3, 78]; every end in a bone or on the base


@pytest.mark.slow
def test_a_bend_in_silicone_converges_under_refinement_where_a_point_bend_does_not():
    """finger_soft's flexor turns at [3, 78] in silicone: 2 T sin(theta/2) spread over the anchor disk."""
    def tip(size, radius):
        with Session(SOFT, [f"mesh.size={size}", "mesh.degree=2", f"cables.flexor.anchor_radius={radius}"]) as s:
            r = s.solve()
            assert r.converged
            return np.array(r.markers["tip"]["position"])
    sizes = (2.0, 1.0, 0.5)
    spread = [tip(h, 1.0) for h in sizes]
    d = [np.linalg.norm(b - a) for a, b in zip(spread[:-1], spread[1:])]
    assert d[1] < 0.7 * d[0]                                # the changes fall with h


@pytest.mark.parametrize("value, message", [(-1.0, ">= 0"), (500.0, "smaller than the cable")])
def test_bad_anchor_radius_is_one_error(value, message):
    raw = load_design(SOFT).raw
    with pytest.raises(DesignError, match=message) as exc:
        parse_design(raw, "soft.toml", [f"cables.flexor.anchor_radius={value}"])
    assert "cables.flexor.anchor_radius" in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.mpi
def test_anchored_cable_serial_equals_mpirun_2(tmp_path, mpirun):
    import json
    tips = []
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        p = mpirun.run([mpirun.skelfem, "simulate", SOFT, "--set", "mesh.size=2", "--out", out,
                        "--no-picture", "-q"], ranks=ranks)
        assert p.returncode == 0, p.stderr
        r = json.loads((out / "result.json").read_text())
        tips.append((np.array(r["markers"]["tip"]["position"]), r["cables"]["flexor"]["tension"]))
    assert np.allclose(tips[0][0], tips[1][0], rtol=0, atol=1e-9)
    assert tips[0][1] == pytest.approx(tips[1][1], rel=1e-9)


def _strip_with_tendon_to_its_edge(anchor_radius):
    """A 4 x 100 strip whose tendon ends on its free edge: the edge cuts the anchor disk in half."""
    return {"format": 1, "name": "strip", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.0, "degree": 2},
            "materials": {"soft": {"E": 1.0, "nu": 0.3}},
            "body": {"outline": [[0, 0], [4, 0], [4, 100], [0, 100]], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[3.2, 0], [3.2, 100]],
                        "stiffness": 100.0, "anchor_radius": anchor_radius}],
            "pins": [{"name": "base", "region": [[-1, -1], [5, 1e-6]], "kind": "fixed"}]}


@pytest.mark.parametrize("radius", [0.0, 1.0, 3.0])
def test_cable_length_is_unchanged_by_a_rigid_rotation(radius):
    # the anchored end is its disk's material centroid, so it turns with the body
    with Session(_strip_with_tendon_to_its_edge(radius)) as s:
        cable = s.model.term("cables", "flexor").cable
        X = s.model.u.function_space.tabulate_dof_coordinates()[:, :2]
        for angle in (0.5 * np.pi, np.pi):
            c, s_ = np.cos(angle), np.sin(angle)
            u = (X @ np.array([[c, s_], [-s_, c]]) - X + [7.0, -3.0]).ravel()
            assert cable.length(u) == pytest.approx(cable.L0, rel=1e-12)
        if radius:
            end = cable.X[-1]                               # the half disk's weighted centroid, below the edge:
            assert end[1] == pytest.approx(100.0 - 96 * radius / (105 * np.pi), abs=0.05 * radius)   # 0.291 r
            assert np.all(np.diff(cable.X[:, 1]) > 0)       # no via point beyond it: the cable never turns back


@pytest.mark.slow
def test_the_anchor_lattice_follows_the_mesh_so_the_anchor_converges_below_its_old_spacing(monkeypatch):
    """A tendon ending inside a strip on a 2 mm anchor: P1 at h = 1, 0.5, 0.25, 0.125 mm.

    With two lattice points per local cell size the anchored end (the disk's weighted mean
    displacement) converges like h^2 (changes 0.0044, 0.0013, 0.00035 mm); with the lattice
    fixed at radius / 4 = 0.5 mm, meshes finer than it see point forces and the end keeps moving
    (0.0050, 0.0020, 0.0021 mm: the log singularity of each point).
    """
    from skelfem.terms import cables

    def ends(limit):
        monkeypatch.setitem(cables.MAX_PER_RADIUS, 2, limit)
        monkeypatch.setitem(cables.PER_RADIUS, 2, min(limit, 8))
        out = []
        for h in (1.0, 0.5, 0.25, 0.125):
            d = strip(length=20.0, width=10.0, size=h, tendon_offset=0.0, contraction=2.0, k=20.0)
            d["cables"][0].update(path=[[5.0, 0.0], [5.0, 14.0]], anchor_radius=2.0)
            with Session(d) as s:
                assert s.solve().converged
                term = s.model.term("cables", "flexor")
                out.append(term.cable.positions(s.model.u.x.array)[-1])
        return [float(np.linalg.norm(b - a)) for a, b in zip(out[:-1], out[1:])]

    following = ends(32)
    fixed = ends(4)
    assert following[2] < 0.4 * following[1] and following[1] < 0.5 * following[0]   # about h^2 (P1)
    assert fixed[2] > 0.5 * fixed[1]                     # no convergence: a point force per lattice point
    assert following[2] < 0.25 * fixed[2]


def test_the_lattice_density_is_two_points_per_local_cell_size_within_bounds():
    from skelfem.terms.cables import MAX_PER_RADIUS, PER_RADIUS, lattice_density
    centre = np.array([5.0, 10.0])
    with Session(strip(length=20.0, width=10.0, size=4.0)) as s:
        assert lattice_density(s.model.mesh, centre, 2.0) == PER_RADIUS[2]      # 2 r / h = 1: the minimum
    with Session(strip(length=20.0, width=10.0, size=0.5)) as s:
        assert 8 < lattice_density(s.model.mesh, centre, 2.0) <= 12              # 2 r / h_min near the disk
        assert lattice_density(s.model.mesh, centre, 20.0) == MAX_PER_RADIUS[2]  # the cap


@pytest.mark.parametrize("dim", [2, 3])
def test_a_wide_anchor_segment_is_rank_one_parts_not_a_dense_block_and_the_hessian_is_exact(dim):
    """An anchored bend and end on a mesh fine enough that their segments couple more than WIDE DOFs:
    their curvature k s B_i^T W_i B_i leaves the Newton matrix for gdim - 1 rank-one parts each, and
    K + the low-rank parts is still the Hessian (central differences of the gradient)."""
    from _taylor import hessian_error

    from skelfem.terms import cables
    if dim == 2:
        d = strip(length=20.0, width=10.0, size=0.5, degree=2, tendon_offset=0.0, contraction=1.0, k=20.0)
        d["cables"][0].update(path=[[5.0, 0.0], [5.0, 10.0], [6.0, 16.0]], anchor_radius=1.5)
    else:
        d = load_design(GEOMETRY / "pillar3d.toml", ["cables.flexor.anchor_radius=3.0", "mesh.size=1.0"]).raw
    with Session(d) as s:
        assert s.solve().converged
        model, term = s.model, s.model.term("cables", "flexor")
        wide = term.cable._segment_blocks()[4]
        assert len(wide) >= 1
        J = term.cable._segment_blocks()[3]
        assert all(len(J[i]) > cables.WIDE for i in wide)
        u = model.u.x.array
        parts = term.low_rank(u)
        assert len(parts) == 1 + (dim - 1) * len(wide)
        x = model.u.vector.copy()                          # (the model's own vector moves with every sync)
        rng = np.random.default_rng(0)
        v = x.duplicate()
        v.array[:] = rng.standard_normal(len(v.array)) * ~model.fixed[:len(v.array)]
        assert hessian_error(model, x, v) < 1e-7
        H = term.cable.hessian(u, term.rest_length)
        assert np.allclose(H, H.T)

"""Per-node contact fields in solution.xdmf (contact_normal_force, contact_friction_force, contact_state) in 2D
and 3D: each piece's nodes sum to result.json's pair totals, and the stick/slip states are the ones the
pair's ``sticking`` share counts."""
import math
import tomllib

import numpy as np
import pytest
from conftest import GEOMETRY

from skelfem import Session
from skelfem.io.xdmf import SLIPPING, STICKING, contact_fields, write_xdmf

G = 9.81


def _sums_match(path, tags, piece, pair):
    """The fields on piece's nodes (those of its region's cells) against pair (forces on its first side, the
    other piece): sums within 1e-6 of the pair's normal magnitude; the share of N on sticking nodes."""
    import meshio
    m = meshio.read(path)
    dim = m.cells[0].data.shape[1] - 1
    cells = m.cells[0].data
    nodes = np.unique(cells[m.cell_data["region"][0] == tags[f"object:{piece}"]])
    normal = m.point_data["contact_normal_force"][:, :dim]
    friction = m.point_data["contact_friction_force"][:, :dim]
    scale = pair["normal_magnitude"]
    assert scale > 0 and np.linalg.norm(pair["friction_force"]) > 0
    assert np.allclose(-normal[nodes].sum(axis=0), pair["normal_force"], rtol=0, atol=1e-6 * scale)
    assert np.allclose(-friction[nodes].sum(axis=0), pair["friction_force"], rtol=0, atol=1e-6 * scale)
    assert np.allclose((normal + friction)[nodes], m.point_data["contact_force"][nodes, :dim], atol=1e-15)
    state = m.point_data["contact_state"]
    assert set(np.unique(state)) <= {0.0, STICKING, SLIPPING}
    return state


@pytest.mark.slow
def test_the_gripper_s_per_node_fields_sum_to_the_pair_and_show_where_it_slips(tmp_path):
    """2D: the gripper closed, then weighed (the first two stages of geometry/gripper_stages.toml)."""
    d = tomllib.loads((GEOMETRY / "gripper_stages.toml").read_text())
    d["stages"] = d["stages"][:2]
    with Session(d) as s:
        r = s.run_stages()
        write_xdmf(tmp_path / "s.xdmf", s.model)
        tags = dict(s.model.tm.tags)
    assert r.converged, r.status
    pair = next(c for c in r.to_dict()["contacts"] if c["between"] == ["body", "box"])
    state = _sums_match(tmp_path / "s.xdmf", tags, "box", pair)
    assert 0 < pair["sticking"] < 1                                          # some nodes stick, some slip
    assert (state == STICKING).any() and (state == SLIPPING).any()


def test_contact_state_weighs_like_the_pair_s_sticking_share():
    """The nodes marked STICKING carry the pair's sticking share of the normal force N that friction counts
    (one piece pair: a box squeezed between two pads, then weighed)."""
    from skelfem.design import parse_design
    from test_objects import _pinch_design
    with Session(parse_design(_pinch_design(0.6))) as s:
        assert s.solve().converged
        s.set({"gravity.acceleration": [0.0, -G]})
        r = s.solve()
        assert r.converged, r.status
        fields = contact_fields(s.model)
        friction = next(t for t in s.model.terms_in("contacts") if hasattr(t, "vertex_states"))
        anchored, slipping, N = friction.vertex_states(s.model.u.x.array)
    pair = r.to_dict()["contacts"][0]
    share = N[anchored & ~slipping].sum() / N[anchored].sum()
    assert share == pytest.approx(pair["sticking"], abs=1e-12)
    assert ((fields["contact_state"] == STICKING).sum() == (anchored & ~slipping & (N > 0)).sum())


@pytest.mark.slow
def test_a_3d_cube_s_per_node_fields_sum_to_the_pair(tmp_path):
    """3D: a cube lands on a block (stage land), then gravity tilts by 20 degrees (stage tilt, mu = 0.5)."""
    from test_objects_3d import _design
    th = math.radians(20.0)
    d = _design([0.0, 0.0, 0.0], solver={"max_iterations": 30})
    d["stages"] = [{"name": "land", "set": {"gravity.acceleration": [0.0, -G, 0.0]}},
                   {"name": "tilt", "set": {"gravity.acceleration": [G * math.sin(th), -G * math.cos(th), 0.0]}}]
    with Session(d) as s:
        r = s.run_stages()
        assert r.converged, r.status
        write_xdmf(tmp_path / "s.xdmf", s.model)
        tags = dict(s.model.tm.tags)
    (pair,) = r.to_dict()["contacts"]
    assert [e["name"] for e in r.to_dict()["stages"]] == ["land", "tilt"]
    state = _sums_match(tmp_path / "s.xdmf", tags, "cube", pair)
    assert (state == STICKING).any()


@pytest.mark.mpi
@pytest.mark.slow
def test_the_per_node_fields_agree_across_two_ranks(tmp_path, mpirun):
    """The gripper closed and weighed under `mpirun -n 2`: the same per-node fields as the serial run."""
    import meshio

    from _designs import toml_text
    d = tomllib.loads((GEOMETRY / "gripper_stages.toml").read_text())
    d["stages"] = d["stages"][:2]
    path = tmp_path / "g.toml"
    path.write_text(toml_text(d))
    fields = {}
    for ranks in (1, 2):
        res = mpirun.run([mpirun.skelfem, "simulate", str(path), "--out", str(tmp_path / str(ranks)), "-q",
                          "--no-picture"], ranks)
        assert res.returncode == 0, res.stdout + res.stderr
        m = meshio.read(tmp_path / str(ranks) / "solution.xdmf")
        order = np.lexsort(m.points.T[::-1])                # the nodes by position (the ranks number them apart)
        fields[ranks] = {k: v[order] for k, v in m.point_data.items()}
    for name in ("contact_normal_force", "contact_friction_force", "contact_state"):
        a, b = fields[1][name], fields[2][name]
        assert np.abs(a).sum() > 0 and np.allclose(a, b, atol=1e-9), name

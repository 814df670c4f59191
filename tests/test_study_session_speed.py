"""studies/session_speed.py at small size: every path of a live Session converges and is counted."""
from _studies import load_study

from conftest import GEOMETRY


def test_session_speed_tiny():
    study = load_study("session_speed")
    res = study.run(GEOMETRY / "finger.toml", delta=0.5, repeats=2, overrides=["mesh.size=4"])
    for key in ("set_contraction", "edit_bone_vertex", "edit_bone_vertex_moved_nodes", "edit_cable_path_same_mesh",
                "edit_bone_vertex_cold"):
        row = res[key]
        assert row["all_converged"], key              # moved nodes: not re-meshed; same mesh: kept
        assert row["time_median"] > 0 and row["newton_iterations_max"] >= 1
    assert res["set_contraction"]["newton_iterations_max"] <= res["edit_bone_vertex_cold"]["newton_iterations_max"]

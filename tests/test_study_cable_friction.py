"""studies/cable_friction.py at a coarse size: no loop without friction, a loop that widens with mu, files."""
import json

import numpy as np
import pytest
from _studies import load_study


@pytest.mark.slow
def test_cable_friction_tiny_loops_widen_with_mu(tmp_path, picture):
    study = load_study("cable_friction")
    res = study.run(size=4.0, steps=4, mus=(0.0, 0.3), width_mus=(0.0, 0.1, 0.3), push_mus=(0.0, 0.3),
                    push_steps=4, out=tmp_path)
    assert res["converged"]
    for part in res["cycles"] + res["push"]:
        assert part["status"] == "converged" and len(part["rows"]) == 1 + 2 * part["steps"]
    cycles = {c["mu"]: c for c in res["cycles"]}

    # mu = 0: up and down agree at every contraction (no history), and the tension is uniform
    rows = cycles[0.0]["rows"]
    up = {r["contraction"]: r["tip_x"] for r in rows if r["branch"] in ("rest", "up")}
    down = {r["contraction"]: r["tip_x"] for r in rows if r["branch"] == "down"}
    assert set(down) <= set(up) and len(down) == 4
    assert max(abs(up[c] - down[c]) for c in down) < 1e-6
    assert all(r["tension_far"] == pytest.approx(r["tension_actuated"], abs=1e-9) for r in rows)

    # mu > 0: a loop, wider for larger mu; pulling, the far end carries less than the actuated end
    width = {w["mu"]: w["loop_width"] for w in res["widths"]}
    assert width[0.0] < 1e-6 < 0.1 < width[0.1] < width[0.3]
    for r in cycles[0.3]["rows"]:
        if r["branch"] == "up" and r["contraction"] > 0:
            assert r["tension_far"] < 0.9 * r["tension_actuated"]
        if r["branch"] == "down" and r["contraction"] > 0:         # paying out: friction holds tension in
            assert r["tension_far"] > r["tension_actuated"]
    full = cycles[0.3]["full"]
    assert full["tension_actuated"] > cycles[0.0]["full"]["tension_actuated"] > full["tension_far"]
    assert cycles[0.3]["full"]["tip_x"] < cycles[0.0]["full"]["tip_x"] < 0      # bent palmar (x < 0)

    # the push: the pre-contracted flexor is taut at rest; no gap between down and back without friction
    push = {p["mu"]: p for p in res["push"]}
    assert all(p["rows"][0]["tension_actuated"] > 1.0 for p in push.values())
    assert push[0.0]["force_gap"] < 1e-6 and push[0.3]["force_gap"] > 1e-3
    assert all(max(r["force"] for r in p["rows"]) > 1.0 for p in push.values())

    saved = json.loads((tmp_path / "cable_friction.json").read_text())
    assert [c["mu"] for c in saved["cycles"]] == [0.0, 0.3]
    lines = (tmp_path / "cable_friction_cycle.csv").read_text().splitlines()
    assert lines[0].startswith("mu,branch,contraction,tip_x") and len(lines) == 1 + 2 * 9
    lines = (tmp_path / "cable_friction_push.csv").read_text().splitlines()
    assert lines[0].startswith("mu,branch,travel,force") and len(lines) == 1 + 2 * 9
    picture(tmp_path / "cable_friction.png", 1000, 400)
    picture(tmp_path / "cable_friction_push.png", 1000, 400)
    picture(tmp_path / "cable_friction_width.png", 500, 400)
    assert not list(tmp_path.glob(".*"))                   # no temporary files left behind
    assert np.isfinite(saved["widths"][-1]["loop_width"])


def test_loop_width_pairs_the_branches():
    study = load_study("cable_friction")
    rows = [{"branch": "rest", "contraction": 0.0, "tip_x": 10.0}, {"branch": "up", "contraction": 1.0, "tip_x": 5.0},
            {"branch": "up", "contraction": 2.0, "tip_x": 0.0}, {"branch": "down", "contraction": 1.0, "tip_x": 4.0},
            {"branch": "down", "contraction": 0.0, "tip_x": 9.5}]
    assert study.loop_width(rows) == (1.0, 1.0)
    assert np.isnan(study.loop_width(rows[:3])[0])

"""studies/design_optimize_finger.py at a tiny size: gradient and gradient-free runs of one task."""
import pytest

from _studies import load_study


@pytest.mark.slow
def test_design_optimize_finger_tiny(tmp_path):
    res = load_study("design_optimize_finger").run(max_gradient_free=8, out=tmp_path, max_evaluations=4)
    assert (tmp_path / "design_optimize_finger.json").exists() and (tmp_path / "optimized.toml").exists()
    g, f = res["gradient"], res["gradient_free"]
    assert g["objective"] < res["start"] and g["improvement"] > 0.3       # two evaluations of both contractions
    assert g["solves"] == 4 and g["evaluations"] == 2
    assert min(g["clearances"].values()) >= -1e-4 and g["fabricate"]["ok"], g
    assert abs(g["fresh"] - g["objective"]) <= g["fresh_error_estimate"]     # the moved mesh against a fresh one
    assert f["evaluations"] <= 8 and f["solves"] == 2 * f["evaluations"]
    assert f["solves_to_reach_gradient_optimum"] is None      # 8 evaluations of COBYLA do not get there


def test_the_kept_run_meets_the_floor_and_the_guide_quotes_it():
    """studies/output/design_optimize_finger (the full run): >= 30 % better than the hand-made finger in at
    most 30 gradient evaluations, stopped by the fabrication constraints (active) and no bound, COBYLA
    not there in 5 x the solves, the fresh mesh within the error estimate, and fabricate's planning pass
    accepts the optimum; the design-gradients guide quotes these numbers."""
    import json
    from pathlib import Path

    from skelfem.design.design_task import load_task
    from skelfem.design.parse import load_design
    root = Path(__file__).resolve().parents[1]
    kept = root / "studies" / "output" / "design_optimize_finger"
    res = json.loads((kept / "design_optimize_finger.json").read_text())
    g, f = res["gradient"], res["gradient_free"]
    assert g["improvement"] >= 0.3 and g["evaluations"] <= 30
    assert sum(1 for v in g["clearances"].values() if abs(v) < 1e-4) >= 2
    assert min(g["clearances"].values()) >= -1e-4
    task = load_task(root / "studies" / "finger_reach_task.toml", load_design(root / "geometry" / "finger.toml"))
    for v in task.variables:
        final = g["variables"][v.key]
        assert v.lower + 1e-3 < final < v.upper - 1e-3, (v.key, final)
    reached = f["solves_to_reach_gradient_optimum"]
    assert (reached is None and f["solves"] >= 5 * g["solves"]) or reached >= 5 * g["solves"]
    assert abs(g["fresh"] - g["objective"]) <= max(g["fresh_error_estimate"], 0.01 * g["objective"])
    assert g["fabricate"]["ok"]
    guide = (root / "docs" / "guide" / "design-gradients.md").read_text()
    assert f"objective (start {res['start']:.2f}) | {g['objective']:.3f} ({100 * g['improvement']:.1f} % lower) | " \
           f"{f['objective']:.3f} ({100 * f['improvement']:.1f} % lower) |" in guide
    assert f"| evaluations / solves | {g['evaluations']} / {g['solves']} | {f['evaluations']} / {f['solves']} |" in guide
    assert f"gives {g['fresh']:.3f} ± {g['fresh_error_estimate']:.3g}" in guide
    entry = json.loads((kept / "min_entry_angle_30" / "design_optimize_finger.json").read_text())
    assert entry["constraints"]["min_entry_angle"] == 30.0 and abs(entry["gradient"]["clearances"]["min_entry_angle"]) < 1e-4
    assert f"SLSQP converges at {entry['gradient']['objective']:.3f} ({100 * entry['gradient']['improvement']:.1f} % lower) " \
           f"in {entry['gradient']['evaluations']} evaluations ({entry['gradient']['solves']} solves)" in " ".join(guide.split())
    assert f"after {entry['gradient_free']['solves_to_reach_gradient_optimum']} solves" in guide


def test_the_kept_optimum_fabricates():
    from pathlib import Path

    import gmsh  # noqa: F401  (imported here, in the main thread: plan() probes in a worker thread)

    from skelfem.design.parse import load_design
    from skelfem.fabricate.plan import plan
    root = Path(__file__).resolve().parents[1]
    kept = root / "studies" / "output" / "design_optimize_finger"
    p = plan(load_design(kept / "optimized.toml"))
    assert any("sheath" in note for note in p.notes)      # the guide says so
    p = plan(load_design(kept / "min_entry_angle_30" / "optimized.toml"))
    assert not any("sheath" in note for note in p.notes)  # min_entry_angle = 30 keeps the channel unsheathed

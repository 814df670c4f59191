"""studies/editor_latency3d.py at a tiny size: it drives Chromium, drags and turns a 3D bone."""
import json

import pytest
from _studies import load_study


@pytest.mark.slow
def test_editor_latency3d_tiny(tmp_path, picture):
    res = load_study("editor_latency3d").run(sizes=(6.0,), moves=4, drags=1, out=tmp_path)
    (case,) = res["cases"]
    assert case["design"] == "finger3d_h6.toml" and 1000 < case["dofs"] < 5000
    for kind, part in (("bone-move", "move"), ("bone-turn", "turn")):
        r = case[part]["rendered"][kind]
        assert r["n"] >= 1 and 0 < r["p50"] <= r["p95"] < 60_000
        assert case[part]["every_event"][kind]["n"] >= 4                  # every move is shown, none lost
        assert case[part]["rendered"]["release"]["n"] == 1
        assert "edit (moved nodes)" in case[part]["server_ms"]
        assert case[part]["certificates"]["converged_above_tolerance"] == 0
        assert case[part]["certificates"]["last"] == "converged"
    assert case["console_errors"] == [] and res["load_average"] and "load average" in res["uptime"]
    assert json.loads((tmp_path / "latency3d.json").read_text())["cases"][0]["dofs"] == case["dofs"]
    picture(tmp_path / "editor_latency3d.png", 1000, 700)


def test_editor_latency3d_refuses_a_bad_size(capsys):
    with pytest.raises(SystemExit) as exc:
        load_study("editor_latency3d").main(["--sizes", "0", "--out", "/nonexistent"])
    assert exc.value.code == 1 and capsys.readouterr().err.startswith("error: --sizes")

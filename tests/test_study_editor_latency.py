"""studies/editor_latency.py at a tiny size: it drives Chromium, measures both kinds of drag and the API."""
import json

import pytest
from _studies import load_study


@pytest.mark.slow
def test_editor_latency_tiny(tmp_path, picture):
    res = load_study("editor_latency").run(moves=4, drags=1, api=2, out=tmp_path, sizes=())
    assert res["design"] == "finger.toml" and res["dofs"] > 1000 and res["sizes"] == []
    slider = res["contraction"]["rendered"]["contraction"]
    assert slider["n"] >= 1 and 0 < slider["p50"] <= slider["p95"] < 60_000
    assert res["contraction"]["every_event"]["contraction"]["n"] >= 4       # every move is shown, none lost
    assert res["vertex"]["rendered"]["release"]["n"] == 1                   # the first frame after the drag
    assert res["vertex"]["settled"]["release"]["n"] == 1                    # ... and its converged picture
    assert res["vertex"]["settled"]["release"]["p50"] >= res["vertex"]["rendered"]["release"]["p50"]
    assert res["vertex"]["every_event"]["vertex"]["n"] >= 4
    assert "edit (moved nodes)" in res["vertex"]["server_ms"] and "set" in res["contraction"]["server_ms"]
    assert res["api"]["one_vertex_ms"]["n"] == 2 and res["api"]["hows"] == ["edit (re-meshed)"]
    assert res["console_errors"] == [] and res["load_average"] and "load average" in res["uptime"]
    assert res["gc"]["longest_ms"] >= 0 and len(res["gc"]["collections"]) == 3
    assert json.loads((tmp_path / "latency.json").read_text())["api"]["one_vertex_ms"]["n"] == 2
    picture(tmp_path / "editor_latency.png", 1000, 700)


def test_editor_latency_refuses_a_bad_size(capsys):
    with pytest.raises(SystemExit) as exc:
        load_study("editor_latency").main(["--sizes", "0", "--out", "/nonexistent"])
    assert exc.value.code == 1 and capsys.readouterr().err.startswith("error: --sizes")

"""The editor's server without a browser: JSON API, guards, latest-wins worker, saving, CLI.

A real uvicorn server on a free port of 127.0.0.1 serves a copy of
geometry/finger.toml (one per module); requests go over real sockets.
"""
import copy
import http.client
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import tomllib

import numpy as np
import pytest
from _hardening import request
from conftest import GEOMETRY, MPI_ENV, ROOT

from skelfem.editor import engine as engine_mod
from skelfem.editor.savefile import SaveError, render, target
from skelfem.editor.worker import Superseded, Worker


@pytest.fixture(scope="module")
def design():
    return tomllib.loads((GEOMETRY / "finger.toml").read_text())




def solve(ed, d):
    return request(ed, "POST", "/api/solve", d)


def tip(answer):
    return np.array(answer["markers"]["tip"]["position"])


# -- the API ------------------------------------------------------------------------------------------
def test_solve_returns_result_and_mesh(editor, design):
    from skelfem import Session
    status, a = solve(editor, design)
    assert status == 200 and a["converged"]
    for key in ("format", "design", "status", "newton_iterations", "dofs", "cells", "markers", "cables", "pins",
                "timings", "residual_history"):
        assert key in a
    m = a["mesh"]
    assert m["dim"] == 2 and len(m["x"]) == len(m["y"]) and len(m["cells"]) == a["cells"] == len(m["regions"])
    assert set(m["regions"]) == {1, 2, 3, 4} and m["region_names"]["1"] == "body"
    assert {c["name"] for c in m["cables"]} == {"flexor", "lig1_palmar", "lig1_dorsal", "lig2_palmar", "lig2_dorsal"}
    flexor = next(c for c in m["cables"] if c["name"] == "flexor")
    assert len(flexor["via"]) > 3 * len(design["cables"][0]["path"])     # the sketch cut at every mesh edge
    assert flexor["tension"] > 0 and not flexor["slack"]
    assert any(c["slack"] for c in m["cables"] if c["name"].startswith("lig"))
    assert np.allclose(m["markers"]["tip"], a["markers"]["tip"]["position"], atol=1e-4)
    assert len(m["fields"]["stretch"]) == a["cells"] and min(m["fields"]["stretch"]) > 0.5
    with Session(GEOMETRY / "finger.toml") as s:
        cold = s.solve()
    assert np.allclose(tip(a), cold.markers["tip"]["position"], atol=1e-4)


def test_live_parameter_is_set_geometry_is_edited(editor, design):
    solve(editor, design)
    d = copy.deepcopy(design)
    d["cables"][0]["contraction"] = 6.0
    status, a = solve(editor, d)
    assert status == 200 and a["editor"]["how"] == "set"
    moved = copy.deepcopy(d)
    moved["bones"][0]["outline"][0] = [6.5, 8]
    status, b = solve(editor, moved)
    assert status == 200 and b["editor"]["how"] == "edit (re-meshed)" and b["converged"]
    status, c = solve(editor, moved)
    assert c["editor"]["how"] == "unchanged" and np.allclose(tip(c), tip(b))
    assert not np.allclose(tip(a), tip(b), atol=1e-3)


def test_drafts_move_the_nodes_and_the_release_re_meshes(design):
    eng = engine_mod.Engine(copy.deepcopy(design), "finger.toml", frame_budget=None)   # drafts solved to the end
    try:
        cells = eng.first["cells"]
        d = copy.deepcopy(design)
        d["bones"][0]["outline"][0][0] += 0.3
        draft = eng.solve(d, draft=True)
        assert draft["editor"]["how"] == "edit (moved nodes)" and draft["editor"]["draft"] and draft["converged"]
        assert draft["cells"] == cells and draft["mesh"] is not None
        final = eng.solve(d)
        assert final["editor"]["how"] == "edit (re-meshed)" and not final["editor"]["draft"]
        motion = np.linalg.norm(tip(final) - final["markers"]["tip"]["reference"])
        assert np.linalg.norm(tip(final) - tip(draft)) < 0.01 * motion     # the two meshes' discretisation error
        e = copy.deepcopy(d)
        e["markers"]["tip"][0] -= 1.0                       # outlines unchanged: the mesh is kept
        kept = eng.solve(e)
        assert kept["editor"]["how"] == "edit (same mesh)" and kept["cells"] == final["cells"]
    finally:
        eng.close()


def test_bad_design_is_422_with_key_and_keeps_the_last_result(editor, design):
    status, good = solve(editor, design)
    bad = copy.deepcopy(design)
    bad["bones"][0]["outline"][0] = [-5, 8]
    status, err = solve(editor, bad)
    assert status == 422 and err["key"] == "bones.proximal.outline"
    assert "finger.toml: bones.proximal.outline:" in err["error"] and "inside" in err["error"]
    bad = copy.deepcopy(design)
    bad["cables"][0]["path"][1] = [-3, 78]
    status, err = solve(editor, bad)
    assert status == 422 and err["key"] == "cables.flexor.path" and "leaves the body" in err["error"]
    bad = copy.deepcopy(design)
    bad["materials"]["pla"]["nu"] = 0.7
    assert solve(editor, bad) == (422, {"error": "finger.toml: materials.pla.nu: must lie in (-1, 0.5), got 0.7",
                                        "key": "materials.pla.nu"})
    status, again = solve(editor, design)
    assert status == 200 and again["editor"]["how"] == "unchanged" and np.allclose(tip(again), tip(good))


def test_solver_failure_is_reported_and_the_server_goes_on(editor, design):
    d = copy.deepcopy(design)
    d["cables"][0]["contraction"] = 30.0
    d["solver"] = {"steps": 1, "max_iterations": 1}
    status, a = solve(editor, d)
    assert status == 200 and not a["converged"] and a["mesh"] is None and a["markers"] is None
    status, b = solve(editor, design)
    assert status == 200 and b["converged"]


def test_internal_error_is_500_then_the_solver_starts_again(editor, design):
    solve(editor, design)
    session = editor.engine.session
    real = session.solve

    def broken(*args, **kwargs):
        session.solve = real
        raise RuntimeError("boom")
    session.solve = broken
    d = copy.deepcopy(design)
    d["cables"][0]["contraction"] = 7.5
    status, err = solve(editor, d)
    assert status == 500 and "RuntimeError: boom" in err["error"]
    status, a = solve(editor, d)
    assert status == 200 and a["converged"] and a["cables"]["flexor"]["contraction"] == 7.5


@pytest.mark.slow
def test_ik_reaches_a_target_with_tendons_only(editor, design):
    d = copy.deepcopy(design)
    d["cables"][0]["contraction"] = 5.5              # one tendon: reachable targets lie on its tip curve
    goal = tip(solve(editor, d)[1]).tolist()
    solve(editor, design)
    status, a = request(editor, "POST", "/api/ik", {"design": design, "marker": "tip", "target": goal})
    assert status == 200, a
    ik = a["ik"]
    assert ik["reached"] and ik["error"] < ik["tol"] and np.allclose(tip(a), goal, atol=ik["tol"])
    assert abs(a["cables"]["flexor"]["contraction"] - 5.5) < 0.05
    cables = {c["name"]: c for c in a["new_design"]["cables"]}
    assert cables["flexor"]["contraction"] == ik["contractions"]["cables.flexor.contraction"] != 8.0
    assert all("contraction" not in c for n, c in cables.items() if n != "flexor")     # ligaments untouched
    status, far = request(editor, "POST", "/api/ik", {"design": design, "marker": "tip", "target": [200.0, 300.0]})
    assert status == 200 and not far["ik"]["reached"] and far["ik"]["status"] != "reached"
    assert request(editor, "POST", "/api/ik", {"design": design, "marker": "nope", "target": [0, 0]})[0] == 422
    assert request(editor, "POST", "/api/ik", {"design": design, "marker": "tip", "target": [0]})[0] == 400


def test_design_endpoint_and_page(editor):
    status, d = request(editor, "GET", "/api/design")
    assert status == 200 and d["file"] == "finger.toml" and d["dim"] == 2 and not d["readonly"]
    assert "cables.flexor.contraction" in d["parameters"]
    status, page = request(editor, "GET", "/")
    assert status == 200 and b"editor.js" in page
    for name in ("editor.js", "editor.css"):
        assert request(editor, "GET", f"/static/{name}")[0] == 200
    assert request(editor, "GET", "/static/../server.py")[0] == 404
    assert request(editor, "GET", "/static/nothing.js")[0] == 404


# -- guards -----------------------------------------------------------------------------------------------
def test_listens_on_loopback_only(editor):
    assert editor.sock.getsockname()[0] == "127.0.0.1"
    addresses = set()
    try:
        addresses = {a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)}
    except OSError:
        pass
    for addr in addresses - {"127.0.0.1"}:
        with pytest.raises(OSError):
            socket.create_connection((addr, editor.port), timeout=2).close()


@pytest.mark.parametrize("headers", [{"Host": "evil.example:80"}, {"Host": "evil.example"},
                                     {"Host": "127.0.0.1"}, {"Host": "127.0.0.1:1"},
                                     {"Origin": "http://evil.example"}, {"Origin": "null"}])
def test_foreign_host_or_origin_is_refused(editor, design, headers):
    status, err = request(editor, "GET", "/api/design", headers=headers)
    assert status == 403 and "error" in err
    assert request(editor, "POST", "/api/solve", design, headers=headers)[0] == 403
    assert request(editor, "GET", "/", headers=headers)[0] == 403


def test_own_hosts_are_served(editor):
    for host in (f"127.0.0.1:{editor.port}", f"localhost:{editor.port}"):
        assert request(editor, "GET", "/api/design", headers={"Host": host,
                                                             "Origin": f"http://{host}"})[0] == 200


def _ws_handshake(port, host, origin=None) -> bytes:
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    lines = ["GET /api/live HTTP/1.1", f"Host: {host}", "Upgrade: websocket", "Connection: Upgrade",
             "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13"]
    if origin:
        lines.append(f"Origin: {origin}")
    s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    data = s.recv(4096)
    s.close()
    return data


def test_websocket_guards(editor):
    assert _ws_handshake(editor.port, f"127.0.0.1:{editor.port}").startswith(b"HTTP/1.1 101")
    assert _ws_handshake(editor.port, "evil.example").startswith(b"HTTP/1.1 403")
    assert _ws_handshake(editor.port, f"127.0.0.1:{editor.port}", "http://evil.example").startswith(b"HTTP/1.1 403")


def test_bodies_are_checked(editor, design):
    assert request(editor, "POST", "/api/solve", raw=b"{not json")[0] == 400
    assert request(editor, "POST", "/api/solve", raw=b'{"format": NaN}')[0] == 400
    assert request(editor, "POST", "/api/solve", raw=b"\xff\xfe")[0] == 400
    assert request(editor, "POST", "/api/solve", raw=b"[" * 100000 + b"]" * 100000)[0] in (400, 413)
    assert request(editor, "POST", "/api/solve", raw=b"[1, 2]")[0] == 400
    assert request(editor, "POST", "/api/solve", raw=json.dumps(design).encode(),
                   headers={"Content-Type": "text/plain"})[0] == 415
    big = json.dumps({"format": 1, "pad": "x" * (2 << 20)}).encode()
    assert request(editor, "POST", "/api/solve", raw=big)[0] == 413
    assert request(editor, "GET", "/api/solve")[0] == 405


def _chunked_oversize(port) -> bytes:
    s = socket.create_connection(("127.0.0.1", port), timeout=20)
    s.sendall(f"POST /api/solve HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
              "Transfer-Encoding: chunked\r\n\r\n".encode())
    chunk = b"x" * 65536
    try:
        for _ in range(40):
            s.sendall(b"%x\r\n" % len(chunk) + chunk + b"\r\n")
    except OSError:
        pass
    data = s.recv(4096)
    s.close()
    return data


def test_survives_100_malformed_requests_then_answers(editor, design):
    port = editor.port
    garbage = [b"\x00\x01\x02 garbage\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n", b"POST /api/solve HTTP/1.1\r\n\r\n",
               f"POST /api/solve HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 5\r\n"
               "Content-Type: application/json\r\n\r\n{{{{{".encode(),
               f"POST /api/solve HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: -1\r\n\r\n".encode(),
               f"GET /{'a' * 70000} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()]
    bodies = [b"{", b"null", b'"text"', b'{"format": 1}', json.dumps({"format": 1, "dim": 2, "body": 5}).encode(),
              b'{"format": Infinity}', json.dumps({**design, "bones": "no"}).encode()]
    for i in range(100):
        if i % 3 == 0:
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(garbage[i % len(garbage)])
            try:
                s.recv(1024)
            except OSError:
                pass
            s.close()
        elif i % 3 == 1:
            status, _ = request(editor, "POST", "/api/solve", raw=bodies[i % len(bodies)])
            assert 400 <= status < 500
        else:
            assert request(editor, "POST", "/api/ik", raw=bodies[i % len(bodies)])[0] in (400, 422)
    assert _chunked_oversize(port).startswith(b"HTTP/1.1 413")
    status, a = solve(editor, design)
    assert status == 200 and a["converged"]


# -- saving ------------------------------------------------------------------------------------------------
def test_save_keeps_comments_and_reloads_to_the_same_result(editor, design):
    from skelfem import Session
    d = copy.deepcopy(design)
    d["bones"][1]["outline"][0] = [6.5, 44]
    d["cables"][0]["contraction"] = 7.25
    status, a = solve(editor, d)
    assert status == 200
    status, saved = request(editor, "POST", "/api/save", {"design": d})
    assert status == 200 and saved["file"] == "finger.toml"
    path = editor.folder / "finger.toml"
    text = path.read_text()
    assert "# A cable-driven finger after the paper's EcoFlex/PLA finger" in text
    assert "# one load step: the energy line search needs no ramp here" in text
    assert "contraction = 7.25" in text and "outline = [[6.5, 44], [14, 44], [14, 68], [6, 68]]" in text
    assert "pla = { E = 3000.0, nu = 0.35, density = 1240.0 }" in text
    with Session(path) as s:
        r = s.solve()
    assert r.cells == a["cells"]                       # the same mesh: Gmsh runs one thread in the editor too
    assert np.allclose(r.markers["tip"]["position"], tip(a), atol=1e-5)
    shutil.copy(GEOMETRY / "finger.toml", path)


def test_save_as_stays_in_the_folder(editor, design, tmp_path):
    status, saved = request(editor, "POST", "/api/save", {"design": design, "name": "finger_v2.toml"})
    assert status == 200 and (editor.folder / "finger_v2.toml").is_file()
    assert tomllib.loads((editor.folder / "finger_v2.toml").read_text()) == design
    assert request(editor, "POST", "/api/save", {"design": design, "name": "finger_v2.toml"})[0] == 200  # its own
    (editor.folder / "other.toml").write_text("# someone else's\n")
    assert request(editor, "POST", "/api/save", {"design": design, "name": "other.toml"})[0] == 409
    assert (editor.folder / "other.toml").read_text() == "# someone else's\n"
    outside = tmp_path / "outside.toml"
    os.symlink(outside, editor.folder / "link.toml")
    for name, code in [("../escape.toml", 403), ("/etc/escape.toml", 403), ("sub/x.toml", 403), (".hidden.toml", 403),
                       ("x.txt", 400), ("", 400), ("link.toml", 403), (5, 400)]:
        status, err = request(editor, "POST", "/api/save", {"design": design, "name": name})
        assert status == code, (name, status, err)
    assert not outside.exists() and not (editor.folder.parent / "escape.toml").exists()
    bad = copy.deepcopy(design)
    bad["mesh"]["degree"] = 3
    status, err = request(editor, "POST", "/api/save", {"design": bad})
    assert status == 422 and err["key"] == "mesh.degree"
    assert request(editor, "POST", "/api/save", {"design": design, "name": "finger.toml"})[0] == 409
    status, _ = request(editor, "POST", "/api/save", {"design": design, "name": "finger.toml", "overwrite": True})
    assert status == 200 and editor.path.name == "finger.toml"


def test_render_changes_only_what_differs():
    text = ('# top comment\nformat = 1\n\n[mesh]\nsize = 2.0   # keep me\n\n[materials]\n'
            'a = { E = 3000.0, nu = 0.3 }\n\n[[cables]]\nname = "c1"\npath = [[0, 0], [1, 1]]  # sketch\n'
            'stiffness = 20.0\n\n[markers]\ntip = [1, 2]\n')
    old = tomllib.loads(text)
    new = copy.deepcopy(old)
    new["mesh"]["size"] = 1.5
    new["materials"]["a"]["E"] = 2500
    new["cables"][0]["path"][1] = [1.25, 1]
    new["cables"][0]["contraction"] = 2
    out = render(text, new)
    assert "# top comment" in out and "size = 1.5   # keep me" in out and "E = 2500.0" in out
    assert "path = [[0, 0], [1.25, 1]]  # sketch" in out and "contraction = 2" in out
    assert tomllib.loads(out) == new
    more = copy.deepcopy(new)
    more["cables"].append({"name": "c2", "kind": "ligament", "path": [[0, 1], [1, 2]], "stiffness": 1.0})
    del more["markers"]
    out2 = render(text, more)
    assert tomllib.loads(out2) == more and "# top comment" in out2
    assert "name" not in tomllib.loads(render(text, {**new, "name": "design"}, default_name="design"))


def test_save_target_rules(tmp_path):
    own = tmp_path / "d.toml"
    assert target(tmp_path, own, None) == own
    assert target(tmp_path, own, "e.toml") == tmp_path / "e.toml"
    for name in ("../e.toml", "a/b.toml", ".e.toml", "e.TOML", "e", "..", "e\n.toml"):
        with pytest.raises(SaveError):
            target(tmp_path, own, name)


# -- the solver side without the server -------------------------------------------------------------------
def test_flatten_and_live_changes():
    d = {"format": 1, "mesh": {"size": 2.0}, "cables": [{"name": "f", "contraction": 1.0, "path": [[0, 0], [1, 1]]}]}
    flat = engine_mod.flatten(d)
    assert flat["cables.f.contraction"] == 1.0 and flat["cables.#order"] == ("f",) and flat["mesh.size"] == 2.0
    e = copy.deepcopy(d)
    e["cables"][0]["contraction"] = 2.0
    live = {"cables.f.contraction"}
    assert engine_mod.live_changes(flat, engine_mod.flatten(e), live) == {"cables.f.contraction": 2.0}
    e["cables"][0]["path"][1] = [1, 2]
    assert engine_mod.live_changes(flat, engine_mod.flatten(e), live) is None
    assert engine_mod.error_key("f.toml: bones.b.outline: bad", "f.toml") == "bones.b.outline"
    assert engine_mod.error_key("f.toml: body.holes[1]: bad", "f.toml") == "body.holes[1]"
    assert engine_mod.error_key("f.toml: malformed TOML: x", "f.toml") == ""


def test_worker_drops_waiting_requests_never_queues():
    started = threading.Event()
    release = threading.Event()
    ran = []

    def slow(tag):
        def job(engine):
            ran.append(tag)
            if tag == "first":
                started.set()
                release.wait(10)
            return tag
        return job
    w = Worker(engine=None)
    try:
        f1 = w.submit("page", slow("first"))
        assert started.wait(10)
        waiting = [w.submit("page", slow(f"drag{i}")) for i in range(5)]
        other = w.submit("api", slow("api"))
        release.set()
        assert f1.result(10) == "first" and waiting[-1].result(10) == "drag4" and other.result(10) == "api"
        for f in waiting[:-1]:
            with pytest.raises(Superseded):
                f.result(10)
        assert ran == ["first", "drag4", "api"] and w.dropped == 4
    finally:
        w.close()


# -- the command ------------------------------------------------------------------------------------------
def test_cli_bad_input(tmp_path, capsys):
    from skelfem.cli.main import main
    bad = tmp_path / "bad.toml"
    bad.write_text((GEOMETRY / "finger.toml").read_text().replace("[[6, 8], [14, 8]", "[[-6, 8], [14, 8]"))
    assert main(["edit", str(bad), "--no-browser"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "bones.proximal.outline" in err and err.count("\n") == 1
    assert main(["edit", str(GEOMETRY / "finger.toml"), "--port", "70000", "--no-browser"]) == 1
    assert "--port 70000" in capsys.readouterr().err
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    try:
        assert main(["edit", str(GEOMETRY / "finger.toml"), "--port", str(busy.getsockname()[1]), "--no-browser"]) == 1
        assert "cannot listen on 127.0.0.1" in capsys.readouterr().err
    finally:
        busy.close()


@pytest.mark.slow
def test_cli_serves_until_interrupted(tmp_path):
    design = tmp_path / "finger.toml"
    shutil.copy(GEOMETRY / "finger.toml", design)
    env = {**MPI_ENV, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-m", "skelfem", "edit", str(design), "--port", "0", "--no-browser"],
                         cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        assert m, (line, p.stderr.read() if p.poll() is not None else "")
        port = int(m.group(1))
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        conn.request("GET", "/api/design")
        assert conn.getresponse().status == 200
        conn.close()
        p.send_signal(signal.SIGINT)
        assert p.wait(30) == 0
        assert "stopped" in p.stdout.read()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


@pytest.mark.slow
def test_3d_design_opens_editable(tmp_path):
    from skelfem.editor.server import Editor
    shutil.copy(GEOMETRY / "arm3d.toml", tmp_path / "arm3d.toml")
    ed = Editor(tmp_path / "arm3d.toml", port=0).start()
    try:
        status, d = request(ed, "GET", "/api/design")
        assert status == 200 and d["dim"] == 3 and not d["readonly"]
        first = d["first"]
        assert first["converged"] and first["mesh"]["dim"] == 3
        m = first["mesh"]
        assert len(m["cells"]) == len(m["regions"]) and all(len(c) == 3 for c in m["cells"][:10])
        assert max(max(c) for c in m["cells"]) < len(m["y"])
        status, a = solve(ed, d["design"])
        assert status == 200 and a["editor"]["how"] == "unchanged"
    finally:
        ed.stop()


def test_several_bodies_open_solve_and_show_the_forces_between_them(tmp_path):
    """geometry/two_fingers.toml in the editor: both bodies' regions, the contact between them (forces on
    the right finger for the arrows), and a live edit of one body's outline re-meshes."""
    from skelfem.editor.server import Editor
    d = tomllib.loads((GEOMETRY / "two_fingers.toml").read_text())
    d["mesh"]["size"] = 3.0
    from _designs import toml_text
    (tmp_path / "two.toml").write_text(toml_text(d))
    ed = Editor(tmp_path / "two.toml", port=0).start()
    try:
        status, a = solve(ed, d)
        assert status == 200 and a["converged"]
        m = a["mesh"]
        assert {"body:left", "body:right"} <= set(m["region_names"].values())
        assert [c["between"] for c in a["contacts"]] == [["left", "right"]]
        (right,) = [o for o in m["objects"] if o["name"] == "right"]
        assert len(right["points"]) and len(right["outline"]) == 0       # forces on a body: no outline
        d2 = copy.deepcopy(d)
        d2["bodies"][1]["outline"][0][0] -= 1.0                        # the right finger's top corner
        status, b = solve(ed, d2)
        assert status == 200 and b["converged"]
        status, bad = solve(ed, {**d2, "bodies": [d2["bodies"][0], {**d2["bodies"][1], "outline": d2["bodies"][0]["outline"]}]})
        assert status == 422 and bad["key"].startswith("bodies.right.outline")
    finally:
        ed.stop()


def test_a_page_that_asks_gets_the_coordinates_packed_and_the_same_numbers(editor, design):
    """Over the websocket, "packed": true sends the mesh's coordinates as base64 float32 (no float formatted as
    text); they decode to the numbers the same answer has as JSON lists, to float32's precision."""
    import base64

    from _hardening import ws_connect, ws_recv, ws_send

    def message(s) -> dict:
        while True:
            opcode, payload = ws_recv(s)
            if opcode == 1:
                return json.loads(payload)

    def unpack(v) -> np.ndarray:
        return np.frombuffer(base64.b64decode(v["f32"]), dtype="<f4").reshape(v["shape"])

    s = ws_connect(editor.port)
    try:
        ws_send(s, json.dumps({"id": 1, "kind": "solve", "design": design}).encode())
        plain = message(s)["answer"]["mesh"]
        ws_send(s, json.dumps({"id": 2, "kind": "solve", "design": design, "packed": True}).encode())
        packed = message(s)["answer"]["mesh"]
    finally:
        s.close()
    assert isinstance(plain["y"], list) and set(packed["y"]) == {"f32", "shape"}
    for got, want in [(packed["y"], plain["y"]), (packed["x"], plain["x"])] + \
            [(p["via"], q["via"]) for p, q in zip(packed["cables"], plain["cables"])]:
        want = np.asarray(want)
        assert unpack(got).shape == want.shape
        assert np.allclose(unpack(got), want, rtol=1e-6, atol=0)
    assert packed["cells"] == plain["cells"] and packed["markers"] == plain["markers"]


def test_a_coordinate_that_is_not_finite_is_never_packed():
    from skelfem.editor.server import dumps
    assert dumps({"y": np.array([[1.0, 2.0]])}, packed=True).startswith('{"y":{"f32":')
    with pytest.raises(ValueError):
        dumps({"y": np.array([[1.0, np.nan]])}, packed=True)
    with pytest.raises(ValueError):
        dumps({"y": np.array([[1.0, np.inf]])})

"""Every guard of the editor holds for a 3D design it edits: this server's Host and its page's Origin only
(HTTP and websocket), JSON bodies within MAX_BODY, one design per server (a design of the other dimension is
neither solved as a frame of it nor saved over it), saves confined to the design's folder and atomic, and a
bad pose a 422 naming its key while the last equilibrium stays.

One editor on a small 3D block (tests/_hardening.box3d at mesh.size 4: a few hundred DOFs).
"""
import json
import tomllib

import pytest
from _hardening import box3d, request, strip2d, toml_dumps, ws_connect, ws_recv, ws_send


@pytest.fixture(scope="module")
def ed(tmp_path_factory):
    from skelfem.editor.server import Editor
    folder = tmp_path_factory.mktemp("guard3d")
    (folder / "block.toml").write_text("# a 3D block\n" + toml_dumps(box3d()))
    e = Editor(folder / "block.toml", port=0).start()
    yield e
    e.stop()


def ws_message(s) -> bytes:
    """The next text message (pings and pongs skipped)."""
    while True:
        opcode, payload = ws_recv(s)
        if opcode == 1:
            return payload


def posed(angle=2.0, move=(0.2, 0.0, 0.3)) -> dict:
    d = box3d()
    d["bones"][1]["move"] = list(move)
    d["bones"][1]["rotate"] = {"angle": angle, "axis": [0.0, 1.0, 0.0], "centre": [5.0, 5.0, 29.0]}
    return d


def test_a_3d_design_is_served_editable(ed):
    status, d = request(ed, "GET", "/api/design")
    assert status == 200 and d["dim"] == 3 and not d["readonly"] and d["first"]["converged"]


@pytest.mark.parametrize("headers", [{"Host": "evil.example:80"}, {"Host": "127.0.0.1"},
                                     {"Origin": "http://evil.example"}, {"Origin": "null"}])
def test_foreign_hosts_and_origins_are_refused(ed, headers):
    status, a = request(ed, "POST", "/api/solve", posed(), headers=headers)
    assert status == 403 and a["key"] == ""


def test_a_websocket_from_another_origin_is_closed(ed):
    import socket
    s = socket.create_connection(("127.0.0.1", ed.port), timeout=30)
    s.sendall((f"GET /api/live HTTP/1.1\r\nHost: 127.0.0.1:{ed.port}\r\nUpgrade: websocket\r\n"
               "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
               "Sec-WebSocket-Version: 13\r\nOrigin: http://evil.example\r\n\r\n").encode())
    head = s.recv(4096)
    s.close()
    assert b" 101 " not in head.split(b"\r\n", 1)[0] or b"\x88" in head     # refused, or closed at once (1008)


def test_bodies_must_be_json_and_within_the_limit(ed):
    from skelfem.editor.server import MAX_BODY
    assert request(ed, "POST", "/api/solve", raw=json.dumps(posed()).encode(),
                   headers={"Content-Type": "text/plain"})[0] == 415
    big = json.dumps({**posed(), "pad": "x" * (MAX_BODY + 1)}).encode()
    assert request(ed, "POST", "/api/solve", raw=big)[0] == 413
    assert request(ed, "POST", "/api/solve", raw=b"{nope")[0] == 400


def test_a_draft_of_the_other_dimension_is_a_design_and_never_a_frame(ed):
    s = ws_connect(ed.port)
    try:
        ws_send(s, json.dumps({"id": 1, "kind": "solve", "design": posed(), "draft": True}).encode())
        reply = json.loads(ws_message(s))
        assert reply["ok"] and reply["answer"]["editor"]["how"] == "edit (moved nodes)"
        assert reply["answer"]["certificate"]["state"] == "preview"
        ws_send(s, json.dumps({"id": 2, "kind": "solve", "design": strip2d(), "draft": True}).encode())
        reply = json.loads(ws_message(s))
        # a 2D design sent to a 3D editor is a new design (re-meshed), never moved nodes of the 3D mesh
        assert not reply.get("ok") or reply["answer"]["editor"]["how"] == "edit (re-meshed)"
        ws_send(s, json.dumps({"id": 3, "kind": "solve", "design": posed()}).encode())
        reply = json.loads(ws_message(s))
        assert reply["ok"] and reply["answer"]["converged"]
        assert reply["answer"]["certificate"]["state"] == "converged"
    finally:
        s.close()


def test_a_bone_posed_out_of_the_body_is_a_422_at_its_key_and_the_last_answer_stays(ed):
    status, a = request(ed, "POST", "/api/solve", posed(move=(0.0, 0.0, 8.0)))
    assert status == 422 and a["key"] == "bones.b2.solids" and "strictly inside the body" in a["error"]
    status, a = request(ed, "POST", "/api/solve", posed())
    assert status == 200 and a["converged"]


def test_saves_are_confined_atomic_and_keep_the_dimension(ed):
    folder = ed.folder
    for name, code in (("../escape.toml", 403), (".hidden.toml", 403), ("sub/x.toml", 403), ("x.txt", 400)):
        status, a = request(ed, "POST", "/api/save", {"design": posed(), "name": name})
        assert status == code, (name, status, a)
    status, a = request(ed, "POST", "/api/save", {"design": strip2d()})
    assert status == 422 and "3D" in a["error"]
    status, a = request(ed, "POST", "/api/save", {"design": posed()})
    assert status == 200 and a["file"] == "block.toml"
    text = (folder / "block.toml").read_text()
    assert text.startswith("# a 3D block\n") and tomllib.loads(text) == posed()
    assert sorted(p.name for p in folder.iterdir()) == ["block.toml"]         # no temporary file left

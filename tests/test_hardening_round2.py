"""Adversarial inputs, second round: fabrication bounds, the editor's budget, recovery and connections,
full disks, sweeps of non-designs, unit scales, long dynamics and memory across re-meshing edits.

Every test says what the code did before it (each failed then).
"""
from __future__ import annotations

import copy
import errno
import json
import logging
import shutil
import socket
import subprocess
import sys
import threading
import time
import tomllib

import pytest
from conftest import GEOMETRY, MPI_ENV, ROOT

from _hardening import (request, assert_one_error, listing, strip2d, toml_dumps, ws_connect, ws_recv, ws_send)
from skelfem.cli.main import main

FINGER = GEOMETRY / "finger.toml"


def run_cli(capsys, *args) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# == 3. [fabrication] values bounded before any meshing ================================================
# Before: only positivity was checked; channel_diameter 0.01 / 0.001 and wall 1e5 hung inside Gmsh
# (ignoring SIGINT and SIGTERM), wall 0.01 passed every check with an STL needing its normals fixed,
# wall 1000 exited 3; the other tiny or huge values went on to meshing.
FAB_BAD = [("channel_diameter", 0.01), ("channel_diameter", 0.001), ("channel_diameter", 50.0),
           ("anchor_diameter", 0.001), ("pour_diameter", 0.001), ("vent_diameter", 0.005),
           ("peg_diameter", 0.01), ("socket_depth", 0.001), ("socket_depth", 500.0),
           ("wall", 1e5), ("wall", 1000.0), ("wall", 0.01), ("wall", 0.5),
           ("min_wall", 0.001), ("min_wall", 50.0), ("clearance", 0.001), ("clearance", 30.0),
           ("bone_depth", 0.01)]


@pytest.mark.parametrize("key,value", FAB_BAD, ids=[f"{k}={v:g}" for k, v in FAB_BAD])
def test_fabrication_value_out_of_bounds_is_refused_before_meshing(key, value, tmp_path, capsys, monkeypatch):
    import skelfem.design.occ as occ

    def no_meshing(*a, **k):
        raise AssertionError("Gmsh was started for a design that should have been refused")
    monkeypatch.setattr(occ, "gmsh_model", no_meshing)
    out = tmp_path / "fab"
    t0 = time.perf_counter()
    code, _, err = run_cli(capsys, "fabricate", FINGER, "--out", out, "-q", "--set", f"fabrication.{key}={value}")
    assert code == 1, err
    assert_one_error(err, f"fabrication.{key}:")
    assert time.perf_counter() - t0 < 10
    assert not out.exists()


@pytest.mark.parametrize("key,value", [("wall", 1.0), ("wall", 200.0), ("channel_diameter", 0.2),
                                       ("clearance", 0.0), ("min_wall", 0.0)])
def test_fabrication_bounds_keep_the_edges_valid(key, value):
    # the ends of each range validate (wall 1 and 200, channel 0.2 fabricate: see docs/guide/robustness.md)
    from skelfem.design.parse import load_design
    d = load_design(FINGER, [f"fabrication.{key}={value}"])
    assert getattr(d.fabrication, key) == value


def _scaled_strip(s: float) -> dict:
    """strip2d with every length times s (mesh size too): the same shape at another unit scale."""
    d = strip2d()
    d["thickness"] *= s
    d["mesh"]["size"] *= s
    d["body"]["outline"] = [[x * s, y * s] for x, y in d["body"]["outline"]]
    for b in d["bones"]:
        b["outline"] = [[x * s, y * s] for x, y in b["outline"]]
    for c in d["cables"]:
        c["path"] = [[x * s, y * s] for x, y in c["path"]]
        c["contraction"] *= s
    d["pins"][0]["region"] = [[x * s, y * s] for x, y in d["pins"][0]["region"]]
    d["markers"] = {"tip": [5 * s, 60 * s]}
    return d


@pytest.mark.parametrize("scale", [1e-3, 1e5])
def test_fabricating_a_body_too_small_or_too_large_to_print_is_refused(scale, tmp_path, capsys, monkeypatch):
    # before: a 10 um strip went on to Gmsh with its 1.2 mm default channel (and a 6 km one with 0.2 mm
    # features); the defaults are bounded by fabricate, explicit values already when the design is read
    import skelfem.design.occ as occ
    monkeypatch.setattr(occ, "gmsh_model", lambda *a, **k: (_ for _ in ()).throw(AssertionError("meshed")))
    path = tmp_path / "tiny.toml"
    path.write_text(toml_dumps(_scaled_strip(scale)))
    code, _, err = run_cli(capsys, "fabricate", path, "--out", tmp_path / "fab", "-q")
    assert code == 1, err
    assert_one_error(err, ": body:")


# == 1. the editor's interactive budget and a shutdown that does not wait ==============================
@pytest.fixture(scope="module")
def design():
    return tomllib.loads(FINGER.read_text())


@pytest.fixture(scope="module")
def ed(tmp_path_factory):
    """An editor on a copy of finger.toml, with a 1 s header timeout and room for 32 connections."""
    from skelfem.editor import server
    folder = tmp_path_factory.mktemp("designs")
    shutil.copy(FINGER, folder / "finger.toml")
    saved = getattr(server, "HEADER_TIMEOUT", None), getattr(server, "MAX_CONNECTIONS", None)
    server.HEADER_TIMEOUT, server.MAX_CONNECTIONS = 1.0, 32
    try:
        e = server.Editor(folder / "finger.toml", port=0).start()
    finally:
        server.HEADER_TIMEOUT, server.MAX_CONNECTIONS = saved
    yield e
    e.stop()




@pytest.mark.parametrize("size,degree", [(0.05, 1), (0.1, 1), (0.2, 1), (0.5, 2)])
def test_editor_refuses_a_mesh_over_its_budget(ed, design, size, degree):
    # before: accepted; 0.05 mm kept the solver busy for more than 10 minutes with no way to cancel
    d = copy.deepcopy(design)
    d["mesh"] = {"size": size, "degree": degree}
    t0 = time.perf_counter()
    status, a = request(ed, "POST", "/api/solve", d)
    assert status == 422 and a["key"] == "mesh.size", a
    assert "unknowns" in a["error"] and "--max-dofs" in a["error"]
    assert time.perf_counter() - t0 < 5
    status, a = request(ed, "POST", "/api/solve", design)
    assert status == 200 and a["converged"]


def test_editor_budget_over_the_websocket(ed, design):
    # before: the live channel solved it (minutes)
    d = copy.deepcopy(design)
    d["mesh"] = {"size": 0.05, "degree": 1}
    s = ws_connect(ed.port)
    try:
        ws_send(s, json.dumps({"id": 7, "kind": "solve", "design": d}).encode())
        op, payload = ws_recv(s)
        msg = json.loads(payload)
        assert op == 1 and msg["id"] == 7 and not msg["ok"] and msg["status"] == 422 and msg["key"] == "mesh.size"
    finally:
        s.close()


def test_editor_budget_is_configurable(design):
    from skelfem.design.parse import parse_design
    from skelfem.editor.engine import EditError, MAX_DOFS, budget, check_budget
    d = parse_design(design, "finger.toml")
    check_budget(d, budget())                          # the default lets finger.toml through
    with pytest.raises(EditError) as e:
        check_budget(d, budget(500))
    assert e.value.key == "mesh.size" and e.value.status == 422
    assert budget({3: 10}) == {2: MAX_DOFS[2], 3: 10}


@pytest.mark.slow
def test_cli_edit_refuses_a_design_over_the_budget(tmp_path):
    # before: `skelfem edit` accepted it and meshed 1.9 million unknowns before serving
    path = tmp_path / "fine.toml"
    path.write_text(FINGER.read_text().replace("size = 2.0", "size = 0.05"))
    p = subprocess.run([sys.executable, "-m", "skelfem", "edit", str(path), "--port", "0", "--no-browser"],
                       cwd=ROOT, env={**MPI_ENV, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 1
    assert_one_error(p.stderr, "mesh.size:")
    p = subprocess.run([sys.executable, "-m", "skelfem", "edit", str(path), "--max-dofs", "0"],
                       cwd=ROOT, env={**MPI_ENV, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 1
    assert_one_error(p.stderr, "--max-dofs")


@pytest.mark.slow
def test_editor_stop_does_not_wait_for_a_running_solve(tmp_path):
    # before: stop() waited for uvicorn (10 s) and then for the solve (30 s more); the request waited too
    from skelfem.editor.server import Editor
    shutil.copy(FINGER, tmp_path / "finger.toml")
    e = Editor(tmp_path / "finger.toml", port=0).start()
    release = threading.Event()
    blocked = e.worker.submit(("test", 1), lambda eng: release.wait(60))
    answers = []
    t = threading.Thread(target=lambda: answers.append(request(e, "GET", "/api/design")))
    t.start()
    time.sleep(0.5)
    t0 = time.perf_counter()
    try:
        e.stop()
        took = time.perf_counter() - t0
        t.join(10)
        assert took < 5, took
        assert answers and answers[0][0] == 503, answers
        assert blocked.done()
    finally:
        release.set()


@pytest.mark.slow
def test_cli_edit_stops_on_sigint_during_a_long_solve(tmp_path):
    # before: Ctrl-C waited for the solve (minutes at this size)
    import re
    import signal
    path = tmp_path / "finger.toml"
    shutil.copy(FINGER, path)
    p = subprocess.Popen([sys.executable, "-m", "skelfem", "edit", str(path), "--port", "0", "--no-browser",
                          "--max-dofs", "4000000"], cwd=ROOT, env={**MPI_ENV, "PYTHONPATH": str(ROOT)},
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        port = int(re.search(r"http://127\.0\.0\.1:(\d+)/", line).group(1))
        d = tomllib.loads(FINGER.read_text())
        d["mesh"] = {"size": 0.08, "degree": 1}
        body = json.dumps(d).encode()
        s = socket.create_connection(("127.0.0.1", port), timeout=60)
        s.sendall(f"POST /api/solve HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
                  f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
        time.sleep(3)
        t0 = time.perf_counter()
        p.send_signal(signal.SIGINT)
        assert p.wait(15) == 0
        assert time.perf_counter() - t0 < 10
        reply = s.recv(4096)
        assert reply == b"" or reply.startswith(b"HTTP/1.1 503"), reply
        s.close()
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


# == 2. recovery after an unexpected error ==============================================================
def _break_once(obj, name):
    real = getattr(obj, name)

    def broken(*args, **kwargs):
        setattr(obj, name, real)
        raise RuntimeError("injected")
    setattr(obj, name, broken)


@pytest.mark.parametrize("where", ["solve", "set", "edit"])
def test_recovery_from_an_error_when_the_last_good_design_cannot_be_rebuilt(ed, design, where, monkeypatch):
    # before: recovery rebuilt the last good design; when that raised, the Session stayed closed and
    # every later request answered 500
    import skelfem.session as session_mod
    status, _ = request(ed, "POST", "/api/solve", design)
    assert status == 200
    _break_once(ed.engine.session, where)
    real_init, calls = session_mod.Session.__init__, []

    def failing_init(self, d, *a, **k):
        calls.append(d)
        if len(calls) == 1:
            raise RuntimeError("injected: cannot rebuild")
        return real_init(self, d, *a, **k)
    monkeypatch.setattr(session_mod.Session, "__init__", failing_init)
    d = copy.deepcopy(design)
    if where == "edit":
        d["markers"]["extra"] = [10, 50]
    else:
        d["cables"][0]["contraction"] = 7.25 if where == "set" else 8.0
        if where == "solve":
            d["cables"][0]["contraction"] = 6.5
    status, err = request(ed, "POST", "/api/solve", d)
    assert status == 500 and "injected" in err["error"]
    monkeypatch.setattr(session_mod.Session, "__init__", real_init)
    for _ in range(2):
        status, a = request(ed, "POST", "/api/solve", design)
        assert status == 200 and a["converged"], a
    assert request(ed, "GET", "/api/design")[0] == 200


def test_recovery_that_fails_entirely_is_tried_again(ed, design, monkeypatch):
    # before: the engine kept a closed Session: 500 for every request from then on
    import skelfem.session as session_mod
    request(ed, "POST", "/api/solve", design)
    _break_once(ed.engine.session, "solve")
    real_init = session_mod.Session.__init__

    def failing_init(self, *a, **k):
        raise RuntimeError("injected: cannot rebuild")
    monkeypatch.setattr(session_mod.Session, "__init__", failing_init)
    d = copy.deepcopy(design)
    d["cables"][0]["contraction"] = 6.75
    assert request(ed, "POST", "/api/solve", d)[0] == 500
    status, a = request(ed, "POST", "/api/solve", design)
    assert status == 503 and "could not start again" in a["error"]
    monkeypatch.setattr(session_mod.Session, "__init__", real_init)
    status, a = request(ed, "POST", "/api/solve", design)
    assert status == 200 and a["converged"]
    assert request(ed, "GET", "/api/design")[0] == 200


def test_recovery_never_rebuilds_the_design_that_failed(ed, design, monkeypatch):
    # the design being solved when the error came is never rebuilt (only converged ones are kept)
    import skelfem.session as session_mod
    request(ed, "POST", "/api/solve", design)
    built = []
    real_init = session_mod.Session.__init__

    def spy(self, d, *a, **k):
        built.append(d.raw["mesh"]["size"])
        return real_init(self, d, *a, **k)
    monkeypatch.setattr(session_mod.Session, "__init__", spy)
    _break_once(ed.engine.session, "edit")
    d = copy.deepcopy(design)
    d["mesh"]["size"] = 2.5
    assert request(ed, "POST", "/api/solve", d)[0] == 500
    assert request(ed, "GET", "/api/design")[0] == 200      # queued behind the recovery
    assert built == [2.0]
    assert request(ed, "POST", "/api/solve", design)[0] == 200


@pytest.mark.parametrize("name", ["\ud800", "a\udfffb", "\x00", "../x"])
def test_bad_names_are_422_and_the_editor_goes_on(ed, design, name):
    # a guard, not a new fix: a lone surrogate name was accepted before io/outdir.check_name (already
    # fixed); through the editor it must stay a 422 and never turn the server to 500s
    d = dict(design, name=name)
    raw = json.dumps(d).encode()
    status, a = request(ed, "POST", "/api/solve", raw=raw)
    assert status == 422 and a["key"] == "name", a
    assert request(ed, "POST", "/api/solve", design)[0] == 200


# == 7. 3D designs are saved by the editor, never a design of the other dimension over them ============
class _FakeEngine:
    def __init__(self, d):
        self.d = d

    def parse(self, design, budget=True):
        from skelfem.design.parse import parse_design
        return parse_design(design, "x.toml")

    @property
    def design(self):
        return self.d


def test_a_3d_design_saves_with_its_pose_and_a_2d_one_over_it_is_refused(tmp_path):
    # before: /api/save refused every 3D design (the editor showed them read-only); now the editor edits
    # 3D designs and writes them back, comments kept, and refuses a 2D design over a 3D file (one design
    # per server, and its file keeps its dimension)
    import tomllib

    from _hardening import box3d
    from skelfem.design.parse import parse_design
    from skelfem.editor.savefile import SaveError
    from skelfem.editor.server import Editor
    path = tmp_path / "block.toml"
    text = "# a hand-written 3D design\n" + toml_dumps(box3d())
    path.write_text(text)
    ed = object.__new__(Editor)
    ed.path, ed.folder = path, tmp_path
    ed.engine = _FakeEngine(parse_design(box3d(), "block.toml"))
    with pytest.raises(SaveError) as e:
        ed.save(strip2d(), None, False)
    assert e.value.status == 422 and "3D" in e.value.message
    assert path.read_text() == text and listing(tmp_path) == ["block.toml"]
    moved = box3d()
    moved["bones"][1]["move"] = [0.25, 0.0, 0.5]
    moved["bones"][1]["rotate"] = {"angle": 3.5, "axis": [0.0, 1.0, 0.0], "centre": [5.0, 5.0, 29.0]}
    ed.save(moved, None, False)
    written = path.read_text()
    assert written.startswith("# a hand-written 3D design\n") and tomllib.loads(written) == moved
    assert listing(tmp_path) == ["block.toml"]                    # written in place (atomic: no leftovers)
    assert parse_design(tomllib.loads(written), "block.toml").bones[1].pose["angle"] == 3.5


# == 6. connections: header timeout, idle sockets, binary frames, malformed HTTP ========================
def test_half_open_connections_do_not_lock_the_editor_out(ed):
    # before: 64 sockets that sent half a request line made it answer 503 to everyone
    socks = []
    try:
        for _ in range(100):
            s = socket.create_connection(("127.0.0.1", ed.port), timeout=10)
            s.sendall(b"GET / HT")
            socks.append(s)
        time.sleep(0.2)
        t0 = time.perf_counter()
        status, _ = request(ed, "GET", "/api/design", timeout=10)
        assert status == 200
        assert time.perf_counter() - t0 < 5
    finally:
        for s in socks:
            s.close()


@pytest.mark.parametrize("sent", [b"", b"GET / HTTP/1.1\r\n", b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-A: b"])
def test_a_connection_that_does_not_finish_its_headers_is_closed(ed, sent):
    # before: uvicorn kept it open for ever (no header timeout)
    s = socket.create_connection(("127.0.0.1", ed.port), timeout=10)
    try:
        if sent:
            s.sendall(sent)
        t0 = time.perf_counter()
        data = s.recv(4096)
        assert data == b"" and time.perf_counter() - t0 < 5
    finally:
        s.close()


def test_a_keep_alive_connection_with_a_slow_second_request_is_closed(ed):
    # before: only the idle keep-alive timer ran, and a byte of the next request stopped it for ever
    s = socket.create_connection(("127.0.0.1", ed.port), timeout=10)
    try:
        s.sendall(f"GET /favicon.ico HTTP/1.1\r\nHost: 127.0.0.1:{ed.port}\r\n\r\n".encode())
        assert s.recv(4096).startswith(b"HTTP/1.1 204")
        s.sendall(b"G")
        t0 = time.perf_counter()
        assert s.recv(4096) == b"" and time.perf_counter() - t0 < 5
    finally:
        s.close()


@pytest.mark.parametrize("payload", [b"\x00\x01binary", json.dumps({"id": 1, "kind": "solve"}).encode()])
def test_a_binary_websocket_frame_gets_an_error_reply(ed, design, payload):
    # before: a KeyError traceback on the server and the connection dropped without a reply
    s = ws_connect(ed.port)
    try:
        ws_send(s, payload, opcode=2)
        op, data = ws_recv(s)
        msg = json.loads(data)
        assert op == 1 and msg["ok"] is False and msg["status"] == 400 and "binary" in msg["error"]
        ws_send(s, json.dumps({"id": 2, "kind": "solve", "design": design}).encode())
        op, data = ws_recv(s)
        msg = json.loads(data)
        assert msg["id"] == 2 and msg["ok"] and msg["answer"]["converged"]
    finally:
        s.close()


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.setFormatter(logging.Formatter("%(message)s"))
        self.texts = []

    def emit(self, record):
        self.texts.append(self.format(record))


MALFORMED = [b"\x00\x01\x02 garbage\r\n\r\n", b"GET / HTTP/1.1\r\nContent-Length: x\r\n\r\n", b"GET /\x7f HTTP/1.1\r\nHost: x\r\n\r\n",
             b"GET / HTTP/1.1\r\nHost: a\r\nbad header line\r\n\r\n"]


@pytest.mark.parametrize("raw", MALFORMED, ids=["garbage", "length", "target", "header"])
def test_malformed_http_is_one_log_line(ed, raw):
    # before: uvicorn logged "Invalid HTTP request received." with a whole h11 traceback
    handler = _Lines()
    logger = logging.getLogger("uvicorn.error")
    logger.addHandler(handler)
    try:
        s = socket.create_connection(("127.0.0.1", ed.port), timeout=10)
        s.sendall(raw)
        data = s.recv(4096)
        s.close()
        time.sleep(0.1)
    finally:
        logger.removeHandler(handler)
    assert data.startswith(b"HTTP/1.1 400"), data
    assert handler.texts and all("\n" not in t and "Traceback" not in t for t in handler.texts), handler.texts


# == 8. a full, read-only or over-quota disk is bad output (exit 1, one line) in every command ========
def _enospc(code=errno.ENOSPC, name="summary.csv"):
    def write(*a, **k):
        raise OSError(code, __import__("os").strerror(code), name)
    return write


def _sweep_files(tmp_path, design_text=None, cases=1):
    (tmp_path / "strip.toml").write_text(design_text if design_text is not None else toml_dumps(strip2d(size=6.0)))
    values = ", ".join(str(0.5 + 0.25 * i) for i in range(cases))
    (tmp_path / "sw.toml").write_text(f'design = "strip.toml"\nname = "sw"\n'
                                      f'[parameters]\n"cables.flexor.contraction" = [{values}]\n')
    return tmp_path / "sw.toml"


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EROFS])
def test_sweep_summary_on_a_full_disk_is_exit_1(code, tmp_path, capsys, monkeypatch):
    # before: the summary's OSError escaped as an internal error, exit 3
    import skelfem.io.files as files
    sweep = _sweep_files(tmp_path)
    monkeypatch.setattr(files, "write_csv", _enospc(code))
    status, _, err = run_cli(capsys, "sweep", sweep, "--out", tmp_path / "out", "-q")
    assert status == 1, err
    assert_one_error(err, __import__("os").strerror(code))


def test_sweep_case_on_a_full_disk_is_bad_output(tmp_path, capsys, monkeypatch):
    # before: an ENOSPC raised while a case ran (outside a stage) was recorded as an internal error, exit 3
    import skelfem.jobs.run as run
    sweep = _sweep_files(tmp_path)
    monkeypatch.setattr(run, "write_results", _enospc(errno.ENOSPC, "result.json"))
    status, _, err = run_cli(capsys, "sweep", sweep, "--out", tmp_path / "out", "-q")
    assert status == 1, err
    assert_one_error(err)
    rows = (tmp_path / "out" / "summary.csv").read_text()
    assert "bad_output" in rows and "internal_error" not in rows


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EROFS])
def test_any_command_writing_to_a_full_disk_is_exit_1(code, tmp_path, capsys, monkeypatch):
    # before: an OSError out of a command's writer was exit 3 ("internal error: OSError ...")
    import skelfem.jobs.run as run
    path = tmp_path / "strip.toml"
    path.write_text(toml_dumps(strip2d(size=6.0)))
    monkeypatch.setattr(run, "write_results", _enospc(code, "result.json"))
    status, _, err = run_cli(capsys, "simulate", path, "--out", tmp_path / "out", "-q")
    assert status == 1, err
    line = assert_one_error(err, "result.json")
    assert "internal error" not in line


def test_other_os_errors_are_still_internal(tmp_path, capsys, monkeypatch):
    # a guard: only the file system's own refusals are mapped; EBADF stays exit 3
    import skelfem.jobs.run as run
    path = tmp_path / "strip.toml"
    path.write_text(toml_dumps(strip2d(size=6.0)))
    monkeypatch.setattr(run, "write_results", _enospc(errno.EBADF, "result.json"))
    status, _, err = run_cli(capsys, "simulate", path, "--out", tmp_path / "out", "-q")
    assert status == 3
    assert_one_error(err, "internal error")


@pytest.mark.slow
@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_fabricate_on_a_full_disk_is_exit_1(code, tmp_path, capsys, monkeypatch):
    # before: Gmsh's STEP writer raised a plain Exception on a full disk: exit 3
    import os

    import gmsh

    def failing_write(*a, **k):
        raise Exception("Could not open file")
    monkeypatch.setattr(gmsh, "write", failing_write)
    monkeypatch.setattr(os, "fsync", _enospc(code, "bone_proximal.step"))
    out = tmp_path / "fab"
    status, _, err = run_cli(capsys, "fabricate", FINGER, "--out", out, "-q", "--no-picture")
    assert status == 1, err
    assert_one_error(err, os.strerror(code))
    assert not out.exists() and listing(tmp_path) == []


# == 9. a sweep whose design is not a design is refused before any case ================================
NOT_DESIGNS = {"text": "hello world\n", "json": '{"format": 1}', "sweep": 'design = "x.toml"\n',
               "bad value": toml_dumps(dict(strip2d(), thickness=-1.0)), "binary": b"\x00\xff\x00\xfe"}


@pytest.mark.parametrize("kind", sorted(NOT_DESIGNS))
def test_sweep_of_a_file_that_is_not_a_design_is_refused_at_once(kind, tmp_path, capsys):
    # before: every case ran and was written as bad input, with a generic "N of M case(s) failed"
    content = NOT_DESIGNS[kind]
    sweep = _sweep_files(tmp_path, cases=3)
    (tmp_path / "strip.toml").write_bytes(content if isinstance(content, bytes) else content.encode())
    before = listing(tmp_path)
    status, _, err = run_cli(capsys, "sweep", sweep, "--out", tmp_path / "out", "-q")
    assert status == 1, err
    line = assert_one_error(err, ": design: 'strip.toml' is not a usable design file:")
    assert "case" not in line.split("design file:")[0]
    assert listing(tmp_path) == before


def test_sweep_whose_cases_make_the_design_valid_still_runs(tmp_path, capsys):
    # a guard: a design that is valid only with the sweep's overrides is accepted
    d = strip2d(size=6.0)
    d["cables"][0]["contraction"] = 100.0            # more than the tendon's length: refused alone
    sweep = _sweep_files(tmp_path, toml_dumps(d))
    status, _, err = run_cli(capsys, "sweep", sweep, "--out", tmp_path / "out", "-q")
    assert status == 0, err


# == 10. long dynamics: rows streamed to trajectory.csv, bounded memory and result.json ================
def test_decimated_history_keeps_evenly_spaced_entries_and_the_last():
    # before: DynamicsReport kept plain lists: one row (~12 KB with its arrays' share) per step for ever
    from skelfem.fem.dynamics import Decimated
    h = Decimated(8)
    for i in range(1000):
        h.append(i)
    kept = h.values()
    assert len(kept) <= 9 and kept[0] == 0 and kept[-1] == 999 and h[-1] == 999 and h.count == 1000
    steps = {b - a for a, b in zip(kept[:-2], kept[1:-1])}
    assert steps == {h.stride}


@pytest.mark.slow
def test_a_long_dynamics_run_keeps_bounded_history_and_streams_every_row(tmp_path, capsys, monkeypatch):
    # before: result.json held every step's energies and attempts (280 B a step; 1e6 steps allowed) and
    # the trajectory rows were all kept in memory until trajectory.csv was written at the end
    import skelfem.fem.dynamics as dyn
    monkeypatch.setattr(dyn, "KEEP_ROWS", 10, raising=False)
    monkeypatch.setattr(dyn, "KEEP_HISTORY", 10, raising=False)
    d = strip2d(size=6.0, bones=False, contraction=0.0)
    for m in d["materials"].values():
        m["density"] = 1100.0
    d["cables"][0]["schedule"] = [[0.0, 0.0], [0.05, 1.0]]
    d["dynamics"] = {"dt": 0.001, "duration": 0.1, "integrator": "bdf2"}
    path = tmp_path / "long.toml"
    path.write_text(toml_dumps(d))
    out = tmp_path / "out"
    status, _, err = run_cli(capsys, "simulate", path, "--out", out, "-q", "--no-picture")
    assert status == 0, err
    res = json.loads((out / "result.json").read_text())
    hist = res["dynamics"]["energy_history"]
    assert res["dynamics"]["steps"] == 100
    assert len(hist["time"]) <= 11 and hist["time"][-1] == pytest.approx(0.1) and hist["time"][0] == 0.0
    assert len(res["attempts"]) <= 11 and len(res["residual_history"]) <= 11
    lines = (out / "trajectory.csv").read_text().splitlines()
    assert len(lines) == 1 + 101
    assert float(lines[-1].split(",")[0]) == pytest.approx(0.1)


# == 4. answers do not depend on the unit scale ========================================================
def _strip_at(s: float) -> dict:
    """strip2d (mesh 3) with lengths times s, cable stiffness times s (forces scale as s^2, moduli stay)."""
    d = _scaled_strip(s)
    d["mesh"]["size"] = 3.0 * s
    for c in d["cables"]:
        c["stiffness"] *= s
    return d


def _tip(s: float):
    import numpy as np

    from skelfem import Session
    from skelfem.design.parse import parse_design
    with Session(parse_design(_strip_at(s), f"strip{s:g}")) as session:
        r = session.solve()
        assert r.converged, r.status
        return np.array(r.markers["tip"]["position"]) / s, r.newton_iterations


@pytest.mark.slow
@pytest.mark.parametrize("pair", [(1.0, 2e-5), (1e-3, 1e3)], ids=["1um-vs-mm", "um-vs-m"])
def test_the_same_design_at_another_unit_scale_gives_the_same_answer(pair):
    # before: the default Newton atol was 1e-10 N, absolute: the 1.2 um strip "converged" at its start
    # (0 iterations, the tip where it was drawn, 17 % off); now it is relative to the design's force scale
    (a, ia), (b, ib) = _tip(pair[0]), _tip(pair[1])
    assert ia > 0 and ib > 0
    assert abs(a - b).max() <= 1e-6 * abs(a).max(), (a, b)


@pytest.mark.parametrize("scale", [1e-7, 1e-6, 2e4])
def test_a_body_out_of_the_unit_range_is_refused_in_one_line(scale, tmp_path, capsys):
    # before: a 6 nm strip aborted the process inside Gmsh (SIGABRT, no line), a 60 nm one solved with the
    # absolute tolerance, and a 1.2 km one went on to DOLFINx's point location (GJK errors, exit 3 at 1e7 mm)
    path = tmp_path / "scaled.toml"
    path.write_text(toml_dumps(_strip_at(scale)))
    p = subprocess.run([sys.executable, "-m", "skelfem", "simulate", str(path), "--out", str(tmp_path / "o"), "-q"],
                       cwd=tmp_path, env={**MPI_ENV, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 1, (p.returncode, p.stderr[-500:])
    assert_one_error(p.stderr, ": body: its largest extent")
    assert not (tmp_path / "o").exists()


def test_the_default_tolerance_follows_the_force_scale():
    from skelfem.design.parse import parse_design
    from skelfem.design.spec import ATOL_RELATIVE, force_scale
    small, big = parse_design(_strip_at(1e-3), "a"), parse_design(_strip_at(1e3), "b")
    assert small.solver.atol is None
    assert force_scale(big) / force_scale(small) == pytest.approx(1e12)
    # E (1 MPa) x sqrt(area) x thickness: 600 ** 0.5 x 10 = 245 N; the default atol is 2.4e-10 N there
    assert force_scale(parse_design(_strip_at(1.0), "c")) == pytest.approx(600 ** 0.5 * 10)
    assert ATOL_RELATIVE == 1e-12


# == 5. memory across re-meshing edits ===================================================================
def _edits(session, n, start=0):
    from skelfem.design.parse import parse_design
    for i in range(start, start + n):
        session.edit(parse_design(strip2d(size=4.0 + 0.005 * i), "strip"))
        session.solve()


@pytest.mark.slow
def test_re_meshing_edits_leave_no_python_objects_behind():
    # before: every mesh with a new node count left ctypes array and pointer types (made by Gmsh's
    # numpy arrays) in ctypes' process-wide cache: about 6 objects and several KB per edit, for ever
    import ctypes
    import gc

    from skelfem import Session
    from skelfem.design.parse import parse_design
    with Session(parse_design(strip2d(size=4.0), "strip")) as s:
        s.solve()
        _edits(s, 10)
        gc.collect()
        types0, objects0 = len(ctypes._pointer_type_cache), len(gc.get_objects())
        _edits(s, 200, start=10)
        gc.collect()
        assert len(ctypes._pointer_type_cache) - types0 <= 2
        assert len(gc.get_objects()) - objects0 < 500


def _rss_kb() -> float:
    import ctypes
    import os
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024


@pytest.mark.slow
def test_200_re_meshing_edits_grow_rss_by_less_than_2_mb():
    # before: ~70 KB a re-meshing edit of finger.toml (14 MB over 200): petsc4py 3.18 parks collected
    # objects until a collective garbage_cleanup, and DOLFINx's Function.vector wrapper is never
    # freed, so every dropped model's vectors stayed in PETSc; Session now destroys them
    import gc

    from skelfem import Session
    from skelfem.design.parse import parse_design
    base = tomllib.loads(FINGER.read_text())

    def finger(h):
        return parse_design(dict(base, mesh={"size": h, "degree": 1}), "finger.toml")
    with Session(finger(2.0)) as s:
        s.solve()
        for i in range(20):
            s.edit(finger(2.0 + 0.001 * i))
            s.solve()
        gc.collect()
        r0 = _rss_kb()
        for i in range(200):
            s.edit(finger(2.05 + 0.001 * i))
            s.solve()
        gc.collect()
        assert _rss_kb() - r0 < 2048


# == other unbounded readers ===========================================================================
def test_a_sweep_never_reads_an_endless_result_file(tmp_path):
    # before: a case's result.json was read whole: a link to /dev/zero filled memory (MemoryError, exit 3)
    import os
    case = tmp_path / "out" / "c1"
    case.mkdir(parents=True)
    os.symlink("/dev/zero", case / "result.json")
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30));"
            "from pathlib import Path; from skelfem.jobs.sweep import Case, completed;"
            f"print(completed(Path({str(tmp_path / 'out')!r}), Case('c1', (), {{}})))")
    p = subprocess.run([sys.executable, "-c", code], env={**MPI_ENV, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and p.stdout.strip() == "False", p.stderr[-300:]


# == tolerances that ask for no equilibrium ============================================================
@pytest.mark.parametrize("setting,key", [("solver.rtol=1e300", "solver.rtol"), ("solver.rtol=0.5", "solver.rtol"),
                                         ("solver.atol=1e300", "solver.atol"), ("solver.atol=1e3", "solver.atol")])
def test_a_tolerance_that_asks_for_no_equilibrium_is_refused(setting, key, tmp_path, capsys):
    # before: Newton stopped at the unsolved start and reported it "converged" (exit 0)
    path = tmp_path / "strip.toml"
    path.write_text(toml_dumps(strip2d(size=6.0)))
    status, _, err = run_cli(capsys, "simulate", path, "--out", tmp_path / "o", "-q", "--set", setting)
    assert status == 1, err
    assert_one_error(err, f": {key}: must be at most")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["ik", "track"])
@pytest.mark.parametrize("tol", ["1e300", "100", "1e-300"])
def test_an_ik_tolerance_out_of_scale_is_refused(command, tol, tmp_path, capsys):
    # before: --tol 1e300 counted every target as reached (exit 0 beside a useless result), 1e-300 was
    # never met; both went on to mesh and solve
    path = tmp_path / "strip.toml"
    path.write_text(toml_dumps(strip2d(size=6.0)))
    args = ["--marker", "tip", "--tol", tol]
    if command == "ik":
        args += ["--target", "5", "59"]
    else:
        (tmp_path / "t.csv").write_text("x,y\n5,59\n5,58\n")
        args += ["--csv", tmp_path / "t.csv"]
    status, _, err = run_cli(capsys, command, path, "--out", tmp_path / "o", "-q", *args)
    assert status == 1, err
    assert_one_error(err, f"--tol {float(tol):g}: must lie in")
    assert not (tmp_path / "o").exists()


# == bench: unbounded counts and non-finite sizes ======================================================
@pytest.mark.parametrize("args,match", [(["--sizes", "nan"], "--sizes"), (["--sizes", "inf"], "--sizes"),
                                        (["--sizes"] + ["3"] * 21, "--sizes: at most"),
                                        (["--repeats", "1000000000"], "--repeats"),
                                        (["--steps", "1000000000"], "--steps")])
def test_bench_refuses_unbounded_or_non_finite_arguments(args, match, tmp_path, capsys):
    # before: --sizes nan passed "h <= 0" and went on to Gmsh; --repeats / --steps 1e9 ran for ever
    path = tmp_path / "strip.toml"
    path.write_text(toml_dumps(strip2d(size=6.0)))
    status, _, err = run_cli(capsys, "bench", path, "--out", tmp_path / "o", "-q", *args)
    assert status == 1, err
    assert_one_error(err, match)
    assert not (tmp_path / "o").exists()

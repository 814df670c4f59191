"""Helpers of the adversarial suite (tests/test_hardening*.py): a sandbox, TOML text, designs."""
from __future__ import annotations

import copy
import os
import sys
from pathlib import Path

from _designs import toml_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SKELFEM = str(Path(sys.executable).parent / "skelfem")
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
       "MPLBACKEND": "Agg"}


def toml_dumps(d: dict) -> str:
    """TOML text of a design dict (the tests' one writer, tomlkit)."""
    return toml_text(d)


def strip2d(size=4.0, bones=True, contraction=1.0) -> dict:
    """A small 2D strip (10 x 60 mm) with two bones, a tendon, a pinned base and a tip marker."""
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": 10.0,
        "mesh": {"size": size, "degree": 1},
        "materials": {"soft": {"E": 1.0, "nu": 0.3}, "hard": {"E": 1000.0, "nu": 0.35}},
        "body": {"outline": [[0, 0], [10, 0], [10, 60], [0, 60]], "material": "soft"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0], [8, 60]], "stiffness": 1.0,
                    "contraction": contraction}],
        "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [5, 60]},
    }
    if bones:
        d["bones"] = [{"name": "b1", "outline": [[2, 5], [6, 5], [6, 25], [2, 25]], "material": "hard"},
                      {"name": "b2", "outline": [[2, 30], [6, 30], [6, 55], [2, 55]], "material": "hard"}]
    return d


def box3d(size=4.0) -> dict:
    """A small 3D block (10 x 10 x 40 mm) with two box bones, a tendon, a pinned base and a tip marker."""
    return {
        "format": 1, "name": "block", "dim": 3,
        "mesh": {"size": size, "degree": 1},
        "materials": {"soft": {"E": 1.0, "nu": 0.3}, "hard": {"E": 1000.0, "nu": 0.35}},
        "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [10, 10, 40]}}], "material": "soft"},
        "bones": [{"name": "b1", "solids": [{"box": {"min": [3, 3, 4], "max": [7, 7, 18]}}], "material": "hard"},
                  {"name": "b2", "solids": [{"box": {"min": [3, 3, 22], "max": [7, 7, 36]}}], "material": "hard"}],
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 5, 0], [8, 5, 40]], "stiffness": 1.0,
                    "contraction": 1.0}],
        "pins": [{"name": "base", "region": [[-1, -1, -1], [11, 11, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [5, 5, 40]},
    }


def changed(d: dict, *changes) -> dict:
    """Deep copy of d with (path tuple, value) changes; value DELETE removes the key."""
    d = copy.deepcopy(d)
    for path, value in changes:
        node = d
        for p in path[:-1]:
            node = node[p]
        if value is DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return d


DELETE = object()


def listing(root: Path) -> list[str]:
    """Every file and folder under root (hidden ones included), relative, sorted."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        out += [str(rel / n) for n in dirnames + filenames]
    return sorted(out)


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error:")]


def assert_one_error(stderr: str, match: str | None = None) -> str:
    """stderr holds exactly one error: line (and no traceback); returns it."""
    assert "Traceback" not in stderr, stderr
    lines = error_lines(stderr)
    assert len(lines) == 1, stderr
    if match is not None:
        assert match in lines[0], lines[0]
    return lines[0]


# -- raw sockets against an editor (tests/test_hardening_round2.py) -------------------------------------
def request(ed, method, path, body=None, headers=None, raw=None, timeout=60):
    """(status, parsed JSON or text) of one HTTP request to an Editor on 127.0.0.1."""
    import http.client
    import json
    conn = http.client.HTTPConnection("127.0.0.1", ed.port, timeout=timeout)
    h = {"Content-Type": "application/json"} if body is not None or raw is not None else {}
    h.update(headers or {})
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    conn.request(method, path, body=data, headers=h)
    r = conn.getresponse()
    text = r.read()
    conn.close()
    try:
        return r.status, json.loads(text)
    except ValueError:
        return r.status, text


def ws_connect(port: int, timeout: float = 30.0):
    """A socket past the websocket handshake to the editor's /api/live."""
    import base64
    import socket
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /api/live HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = s.recv(1)
        if not chunk:
            raise ConnectionError(head)
        head += chunk
    assert head.startswith(b"HTTP/1.1 101"), head
    return s


def ws_send(s, payload: bytes, opcode: int = 1) -> None:
    """One masked frame (opcode 1 text, 2 binary)."""
    import struct
    mask = os.urandom(4)
    n = len(payload)
    head = bytes([0x80 | opcode])
    if n < 126:
        head += bytes([0x80 | n])
    elif n < 65536:
        head += bytes([0x80 | 126]) + struct.pack(">H", n)
    else:
        head += bytes([0x80 | 127]) + struct.pack(">Q", n)
    s.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))


def _recv_exact(s, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = s.recv(n - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def ws_recv(s) -> tuple[int, bytes]:
    """(opcode, payload) of the next frame from the server."""
    import struct
    b0, b1 = _recv_exact(s, 2)
    n = b1 & 0x7F
    if n == 126:
        n = struct.unpack(">H", _recv_exact(s, 2))[0]
    elif n == 127:
        n = struct.unpack(">Q", _recv_exact(s, 8))[0]
    return b0 & 0x0F, _recv_exact(s, n)

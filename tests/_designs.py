"""Small design dictionaries shared by the tests (parsed with skelfem.design.parse_design)."""
import copy


def strip(length=60.0, width=10.0, size=2.0, degree=1, tendon_offset=3.0, contraction=0.1,
          k=1.0, E=1.0, nu=0.3, thickness=10.0, bones=False):
    """A soft strip standing on its pinned base with one straight tendon at an offset."""
    x_t = width / 2 + tendon_offset
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": thickness,
        "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": E, "nu": nu}, "hard": {"E": 1000.0 * E, "nu": 0.35}},
        "body": {"outline": [[0, 0], [width, 0], [width, length], [0, length]], "material": "soft"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[x_t, 0], [x_t, length]],
                    "stiffness": k, "contraction": contraction}],
        "pins": [{"name": "base", "region": [[-1, -1], [width + 1, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [width / 2, length]},
    }
    if bones:
        d["bones"] = [{"name": "b1", "outline": [[2, 5], [8, 5], [8, 25], [2, 25]], "material": "hard"},
                      {"name": "b2", "outline": [[2, 30], [8, 30], [8, 55], [2, 55]], "material": "hard"}]
    return d


def variant(d, **changes):
    """Deep copy of a design dict with dotted-key changes, e.g. variant(d, **{"mesh.size": 1})."""
    d = copy.deepcopy(d)
    for key, value in changes.items():
        *path, last = key.split(".")
        node = d
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value
    return d


def toml_text(d: dict) -> str:
    """TOML text of a design dict (skelfem.io.files.design_toml), parsed back as a check."""
    import tomllib

    from skelfem.io.files import design_toml
    text = design_toml(d)
    tomllib.loads(text)
    return text


def simulate_refused_before_meshing(d: dict, tmp_path, monkeypatch, capsys, *extra: str, names_file: bool = True) -> str:
    """`skelfem simulate` on design d: exit 1 with one `error: PATH: ...` line (returned without its prefix),
    no traceback, no output folder, and the design never meshed. names_file=False: an argument's error
    (`error: --tol ...`), which names no file."""
    from skelfem.mesh import geometry
    from skelfem.cli.main import main

    def never(*args, **kwargs):
        raise AssertionError("the design was meshed")
    monkeypatch.setattr(geometry, "mesh_design", never)
    path = tmp_path / "design.toml"
    path.write_text(toml_text(d))
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "-q", *extra]) == 1
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    prefix = f"error: {path}: " if names_file else "error: "
    assert len(lines) == 1 and lines[0].startswith(prefix) and "Traceback" not in err, err
    assert not out.exists()
    return lines[0][len(prefix):]


def land_and_tilt(design: dict, theta_deg: float, g: float = 9.81):
    """Solve a 3D design under gravity -y (its objects land), then tilt gravity by theta in the x-y
    plane and solve again, warm (the friction history of the landing kept): (landed, tilted) results."""
    import math

    from skelfem import Session
    th = math.radians(theta_deg)
    with Session(design) as s:
        landed = s.solve()
        assert landed.converged, landed.status
        s.set({"gravity.acceleration": [g * math.sin(th), -g * math.cos(th), 0.0]})
        return landed, s.solve()

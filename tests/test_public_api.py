"""The public surface: skelfem.__all__, read-only designs, typed results a notebook can use."""
from __future__ import annotations

import numpy as np
import pytest

import skelfem
from skelfem import Design, DesignError, Result, Session, Status, load_design

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_all_names_resolve():
    for name in ("Session", "Result", "Design", "DesignError"):
        assert name in skelfem.__all__
    for name in skelfem.__all__:
        assert getattr(skelfem, name) is not None, name
    with pytest.raises(AttributeError):
        _ = skelfem.no_such_name


def test_design_raw_is_a_copy_and_the_design_is_read_only():
    d = load_design(ROOT / "geometry" / "finger.toml")
    raw = d.raw
    raw["materials"]["ecoflex"]["E"] = 123.0
    assert d.raw["materials"]["ecoflex"]["E"] != 123.0          # the design did not change
    with pytest.raises(TypeError):
        d.data["materials"]["ecoflex"]["E"] = 1.0                 # its data is read-only
    assert isinstance(d, Design)
    import copy
    import pickle
    again = pickle.loads(pickle.dumps(d))                           # MPI sends designs between ranks
    assert again.raw == d.raw and copy.deepcopy(d).raw == d.raw
    with pytest.raises(TypeError):
        again.data["name"] = "x"


@pytest.mark.slow
def test_an_edit_through_design_raw_equals_a_fresh_session():
    """The README's own recipe: d = s.design.raw; change E; s.edit(d); s.solve() (it used to keep the old E)."""
    path = ROOT / "geometry" / "finger.toml"
    with Session(path, ["mesh.size=3"]) as s:
        before = s.solve().marker("tip")
        d = s.design.raw
        d["materials"]["ecoflex"]["E"] = 0.2
        s.edit(d)
        edited = s.solve().marker("tip")
    with Session(path, ["mesh.size=3", "materials.ecoflex.E=0.2"]) as fresh:
        expected = fresh.solve().marker("tip")
    assert np.linalg.norm(edited - before) > 0.1                  # the edit did something
    assert np.allclose(edited, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


@pytest.mark.slow
def test_result_fields_arrays_and_plot_without_pyplot():
    import matplotlib
    backend = matplotlib.get_backend()
    with Session(ROOT / "geometry" / "finger.toml", ["mesh.size=3"]) as s:
        r = s.solve()
        X, u, cells = r.displacement()
        s.set({"cables.flexor.contraction": 2.0})
        s.solve()
    assert isinstance(r, Result) and r.converged and r.outcome is Status.CONVERGED and r.status == "converged"
    assert isinstance(r.newton_iterations, int) and r.dofs == 2 * len(X) or r.degree == 2
    tip = r.marker("tip")
    assert tip.shape == (2,) and np.isfinite(tip).all()
    assert r.tension("flexor") == r.to_dict()["cables"]["flexor"]["tension"]
    d = r.to_dict()
    d["markers"]["tip"]["position"] = [0, 0]
    r.markers["tip"]["position"] = [0, 0]
    assert np.allclose(r.marker("tip"), tip)                       # copies all the way
    X2, u2, _ = r.displacement()                                   # the solve's own state, not the later one
    assert np.array_equal(u, u2) and u.shape == X.shape
    ax = r.plot()
    assert ax.figure is not None and matplotlib.get_backend() == backend
    with pytest.raises(DesignError):
        Session({"format": 1, "name": "x"})


def test_status_of_unknown_text_is_diverged():
    assert Status.of("diverged (-3)") is Status.DIVERGED
    assert Status.of("max_iterations") is Status.MAX_ITERATIONS
    assert Status.of("no equilibrium: object ball is not held") is Status.NOT_HELD


# -- a Session is safe to misuse: closed, shared between threads, edited into something it cannot be ---
@pytest.fixture(scope="module")
def small():
    s = Session(ROOT / "geometry" / "finger.toml", ["mesh.size=5"])
    s.solve()
    yield s
    s.close()


def test_a_closed_session_says_so():
    from skelfem.session import SessionError
    s = Session(ROOT / "geometry" / "finger.toml", ["mesh.size=6"])
    s.close()
    s.close()                                                       # twice is fine
    for call in (lambda: s.solve(), lambda: s.set({"cables.flexor.contraction": 1.0}), lambda: s.edit(s.design)):
        with pytest.raises(SessionError, match="closed"):
            call()


def test_a_second_thread_is_refused_while_the_first_is_inside(small):
    import threading

    from skelfem.session import SessionError
    inside, release, errors = threading.Event(), threading.Event(), []
    real = small.solver.solve

    def slow_solve(*args, **kwargs):
        inside.set()
        release.wait(30)
        return real(*args, **kwargs)

    small.solved = False
    small.solver.solve = slow_solve
    try:
        t = threading.Thread(target=lambda: errors.append(small.solve()))
        t.start()
        assert inside.wait(30)
        with pytest.raises(SessionError, match="busy in another thread"):
            small.set({"cables.flexor.contraction": 2.0})
        with pytest.raises(SessionError, match="busy"):
            small.solve()
        release.set()
        t.join(60)
    finally:
        del small.solver.solve
    assert errors and errors[0].converged                           # the first thread's solve is intact
    assert small.solve().converged                                  # and the session still works afterwards


def test_a_failed_edit_leaves_the_session_as_it_was(small):
    """A 2D session edited into a 3D design used to raise IndexError and stay switched to it."""
    before = small.solve().marker("tip")
    design, model = small.design, small.model
    three_d = load_design(ROOT / "geometry" / "finger3d.toml", ["mesh.size=8"])
    with pytest.raises(Exception):   # noqa: B017 (whatever it raises, the session must stay as it was)
        small.edit(three_d)
    assert small.design is design and small.model is model
    assert np.allclose(small.solve().marker("tip"), before)

"""Rigid bones (``bones.NAME.rigid = true``): the reduced derivatives, the limit of stiff elastic bones,
exact rigid motions, and Newton on the finger."""

from pathlib import Path

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import DesignError, SolverSpec, parse_design
from skelfem.fem.model import Model
from skelfem.fem.newton import NewtonSolver
from skelfem.terms.rigid import rotation

from _designs import simulate_refused_before_meshing, strip, variant

from _taylor import taylor_orders

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


def _rigid_strip(size=2.0, rigid=True, E_bone=None):
    """The two-bone strip with a tendon that ends in the upper bone and a load on the lower one."""
    d = strip(length=60.0, width=10.0, size=size, contraction=3.0, k=2.0, bones=True)
    d["cables"] = [{"name": "flexor", "kind": "tendon", "path": [[8.8, 0], [8.8, 50], [6, 52]],
                    "stiffness": 2.0, "contraction": 3.0},
                   {"name": "lig", "kind": "ligament", "path": [[3, 22], [3, 33]], "stiffness": 1.0,
                    "pretension": 0.5}]
    d["loads"] = [{"name": "push", "at": [5.0, 15.0], "force": [0.05, 0.0]}]
    for b in d["bones"]:
        b["rigid"] = rigid
    if E_bone is not None:
        d["materials"]["hard"]["E"] = E_bone
    return d


class Reduced:
    """Pi(z) of a model with rigid bones, z = (free DOFs v, rigid DOFs q of each bone) in the chart at u0:
    bone nodes at c + t + R(theta) (y0 - c), the rest at u0 + v."""

    def __init__(self, session, u0):
        self.s, self.model = session, session.model
        model = self.model
        self.u0 = u0.copy()
        self.free = ~model.slaved & ~model.fixed[:model.n_owned]
        self.nv = int(self.free.sum())
        self.size = self.nv + sum(b.m for b in model.rigid)
        self.x = model.u.vector.copy()
        self.b = model.u.vector.duplicate()

    def state(self, z):
        u = self.u0.copy()
        u[self.free] += z[:self.nv]
        j = self.nv
        for body in self.model.rigid:
            q, d = z[j:j + body.m], body.dim
            y0 = body.X + self.u0[body.dofs]
            c = y0.mean(axis=0)
            u[body.dofs] = c + q[:d] + (y0 - c) @ rotation(q[d:] if d == 3 else q[d], d).T - body.X
            j += body.m
        return u

    def _vec(self, z):
        self.x.array_w[:] = self.state(z)
        self.x.ghostUpdate()
        return self.x

    def energy(self, z):
        return self.model.energy(self._vec(z))

    def gradient(self, z):
        """(grad_v Pi, T^T R_b per bone): T the rigid modes at the state (exact d/dq in 2D)."""
        model = self.model
        model.gradient(self._vec(z), self.b)
        g, u = self.b.array_r.copy(), model.u.x.array
        return np.concatenate([g[self.free]] + [body.reduce(body.modes(u), g) for body in model.rigid])

    def hessian_times(self, d):
        """The model's reduced Hessian at z = 0 times d: K, the border (E, C) and the low-rank parts.

        With the border in K (serial: Border.hosts) q sits on the host rows of K and of the g_i."""
        model, lin, A = self.model, self.s.solver.lin, self.s.solver.A
        self.s.solver.jacobian(self._vec(np.zeros(self.size)))
        border = model.border
        dq = d[self.nv:]
        xf = np.zeros(model.n_owned)
        xf[self.free] = d[:self.nv]
        if border.hosts is not None:
            xf[border.hosts] = dq
            self.x.array_w[:] = xf
            A.mult(self.x, self.b)
            out = self.b.array_r + lin.G @ (lin.c * (lin.G.T @ xf))
            return np.concatenate([out[self.free], out[border.hosts]])
        self.x.array_w[:] = xf
        A.mult(self.x, self.b)
        w = lin.c * (lin.G.T @ xf + lin.H.T @ dq)
        out_f = self.b.array_r + border.E @ dq + lin.G @ w
        out_q = border.E.T @ xf + border.C @ dq + lin.H @ w
        return np.concatenate([out_f[self.free], out_q])


def _perturbed(session, seed=3, scale=0.02, angle=0.01):
    """A state with random free DOFs and each rigid bone moved by a random rigid motion."""
    model = session.model
    model.set_factor(0.8)
    rng = np.random.default_rng(seed)
    u = scale * rng.standard_normal(model.n_owned)
    u[model.fixed[:model.n_owned]] = 0.0
    for body in model.rigid:
        c, d = body.X.mean(axis=0), body.dim
        R = rotation(angle * rng.standard_normal(1 if d == 2 else 3).squeeze(), d)
        u[body.dofs] = c + rng.standard_normal(d) * scale + (body.X - c) @ R.T - body.X
    model.u.x.array[:len(u)] = u
    model.u.vector.ghostUpdate()
    return u


def test_design_rigid_key():
    d = _rigid_strip()
    assert [b.rigid for b in parse_design(d).bones] == [True, True]
    assert [b.rigid for b in parse_design(_rigid_strip(rigid=False)).bones] == [False, False]
    assert parse_design(variant(d, bones=[dict(d["bones"][0], rigid=False), d["bones"][1]]),
                        overrides=["bones.b1.rigid=true"]).bones[0].rigid
    bad = variant(d, bones=[dict(d["bones"][0], rigid=1), d["bones"][1]])
    with pytest.raises(DesignError, match=r"^<design>: bones\.b1\.rigid: must be true or false, got 1$"):
        parse_design(bad)


@pytest.mark.parametrize("embedded", [True, False], ids=["border in K", "border outside K"])
def test_reduced_gradient_and_hessian_match_central_differences(embedded, monkeypatch):
    if not embedded:                    # the MPI path, in serial: the border from K^-1 E
        monkeypatch.setattr(Model, "_border_pattern", lambda self, blocks: ([], None))
    with Session(_rigid_strip()) as s:
        assert (s.model._hosts is not None) == embedded
        u0 = _perturbed(s)
        red = Reduced(s, u0)
        assert len(s.model.rigid) == 2 and red.size == red.nv + 6
        z0 = np.zeros(red.size)
        g = red.gradient(z0)
        rng = np.random.default_rng(5)
        for _ in range(3):
            d = rng.standard_normal(red.size)
            d[red.nv:] *= 0.05                       # rotations of order 0.05 rad per unit
            h = 1e-6
            fd = (red.energy(h * d) - red.energy(-h * d)) / (2 * h)
            assert fd == pytest.approx(g @ d, rel=1e-6)
            Hd = red.hessian_times(d)
            fd_H = (red.gradient(h * d) - red.gradient(-h * d)) / (2 * h)
            assert np.linalg.norm(fd_H - Hd) <= 1e-6 * np.linalg.norm(Hd)
        # the rigid block alone, entry by entry (second differences of Pi(q))
        m0 = red.nv
        e = np.eye(red.size)
        h = 1e-4
        for a in range(m0, red.size):
            col = red.hessian_times(e[a])[m0:]
            fd = (red.gradient(h * e[a])[m0:] - red.gradient(-h * e[a])[m0:]) / (2 * h)
            assert np.allclose(col, fd, rtol=1e-6, atol=1e-7 * np.abs(col).max())
            e_pp = (red.energy(h * e[a]) - 2 * red.energy(z0) + red.energy(-h * e[a])) / h ** 2
            assert e_pp == pytest.approx(col[a - m0], rel=1e-4)


def test_reduced_taylor_remainders_are_second_order():
    with Session(_rigid_strip()) as s:
        red = Reduced(s, _perturbed(s, seed=11))
        d = np.random.default_rng(2).standard_normal(red.size)
        d[red.nv:] *= 0.05
        r1, r2 = taylor_orders(red.energy, red.gradient, red.hessian_times, np.zeros(red.size), d,
                               [1e-2 / 2 ** i for i in range(5)])
        assert np.all(r1 > 1.8) and np.all(r2 > 1.8), (r1, r2)


def test_newton_direction_solves_the_reduced_system():
    """The bordered solve (one factorisation of K, one multi-RHS solve) gives H_red p = -g_red."""
    with Session(_rigid_strip()) as s:
        model = s.model
        u0 = _perturbed(s, seed=4)
        red = Reduced(s, u0)
        x, b, p = model.u.vector.copy(), model.u.vector.duplicate(), model.u.vector.duplicate()
        s.solver.jacobian(x)
        model.residual(x, b)
        assert len(s.solver.lin.c) >= 1              # a taut cable takes part
        s.solver.lin.solve(b, p)
        pa, ba = p.array_r, b.array_r
        u = model.u.x.array
        dq = []
        for body in model.rigid:
            T = body.modes(u).reshape(-1, body.m)
            q, *_ = np.linalg.lstsq(T, pa[body.dofs].ravel(), rcond=None)
            assert np.linalg.norm(T @ q - pa[body.dofs].ravel()) <= 1e-12 * np.linalg.norm(pa)
            dq.append(q)
        z = np.concatenate([pa[red.free]] + dq)
        rhs = red.gradient(np.zeros(red.size))
        assert np.linalg.norm(red.hessian_times(z) - rhs) <= 1e-9 * np.linalg.norm(rhs)
        # the residual on a bone's rows vanishes exactly when its reduced gradient does
        for body in model.rigid:
            T = body.modes(u)
            assert np.allclose(body.reduce(T, ba), rhs[red.nv:][:3] if body is model.rigid[0] else rhs[-3:])


def _rigid_deviation(model) -> float:
    """max over rigid bones of |u_b - its closest rigid motion| (mm; this rank's nodes)."""
    u = model.u.x.array
    out = 0.0
    for body in model.rigid:
        v = u.copy()
        body.snap(v)
        out = max(out, float(np.abs(v[body.dofs] - u[body.dofs]).max(initial=0.0)))
    return out


def test_solution_moves_rigid_bones_rigidly_and_stiff_bones_converge_to_it():
    with Session(_rigid_strip()) as s:
        r = s.solve()
        assert r.converged
        rigid_tip = np.array(r.markers["tip"]["position"])
        assert _rigid_deviation(s.model) <= 1e-12 * s.model.size
        bones = r.bones
        assert set(bones) == {"b1", "b2"} and abs(bones["b2"]["rotation"]) > 0.05
        n_slaved = int(s.model.slaved.sum())
        assert n_slaved > 0
    E = [1e2, 1e3, 1e4]
    diffs = []
    for E_bone in E:
        with Session(_rigid_strip(rigid=False, E_bone=E_bone)) as s:
            r = s.solve()
            assert r.converged
            diffs.append(np.linalg.norm(np.array(r.markers["tip"]["position"]) - rigid_tip))
    slope = np.polyfit(np.log(E), np.log(diffs), 1)[0]
    assert -1.3 <= slope <= -0.7, (diffs, slope)
    assert diffs[-1] < 1e-2


def test_rigid_bones_on_the_finger_converge_quadratically():
    bones = ("proximal", "middle", "distal")
    runs = {}
    for rigid in (False, True):
        with Session(GEOMETRY / "finger.toml", [f"bones.{b}.rigid={str(rigid).lower()}" for b in bones]) as s:
            r = s.solve()
            assert r.converged
            runs[rigid] = (r, s.model.slaved.sum())
            if rigid:
                assert _rigid_deviation(s.model) <= 1e-12 * s.model.size
    (re, _), (rr, slaved) = runs[False], runs[True]
    assert slaved > 0
    assert rr.newton_iterations <= 2 * re.newton_iterations
    tail = np.array(rr.residual_history[-1][-4:])
    assert tail[-1] <= 1e-9 * rr.residual_history[-1][0]
    # quadratic: the last reductions follow r_{k+1} ~ r_k^2 (order above 1.5)
    order = np.log(tail[-1] / tail[-2]) / np.log(tail[-2] / tail[-3])
    assert order > 1.5, tail
    diff = np.linalg.norm(np.array(rr.markers["tip"]["position"]) - np.array(re.markers["tip"]["position"]))
    assert diff < 0.01


def test_rigid_bones_are_refused_where_not_supported():
    """A design is refused when it is read; the solver still refuses a spec given to it directly."""
    d = _rigid_strip()
    with pytest.raises(DesignError, match=r"^<design>: solver\.line_search: 'residual' cannot keep rigid bones"):
        Session(variant(d, **{"solver.line_search": "residual"}))
    with Session(d) as s:
        with pytest.raises(ValueError, match="rigid"):
            NewtonSolver(s.model, SolverSpec(line_search="residual"))


@pytest.mark.parametrize("line_search", ["residual", "none", "trust_region"])
def test_simulate_refuses_line_searches_that_cannot_keep_bones_rigid(line_search, tmp_path, monkeypatch, capsys):
    """One error line naming the key and the rigid bones, exit 1, before meshing and before the output folder."""
    d = variant(_rigid_strip(), **{"solver.line_search": line_search})
    line = simulate_refused_before_meshing(d, tmp_path, monkeypatch, capsys)
    assert line.startswith(f"solver.line_search: '{line_search}' ") and "rigid: b1, b2" in line


def test_line_searches_on_the_energy_keep_rigid_designs_valid():
    for line_search in ("auto", "energy", "curved"):
        d = parse_design(variant(_rigid_strip(), **{"solver.line_search": line_search}))
        assert d.solver.line_search == line_search and all(b.rigid for b in d.bones)
    assert parse_design(variant(_rigid_strip(rigid=False), **{"solver.line_search": "residual"})).bones


def test_a_fixed_pin_box_over_a_rigid_bone_holds_only_the_body_boundary():
    """Pins hold the body's boundary in their box and bones lie strictly inside the body, so a fixed pin's
    box may cover a rigid bone (b1) or touch one (b2): the design is valid and no bone node is pinned."""
    d = variant(_rigid_strip(size=3.0), pins=[{"name": "base", "region": [[-1, -1], [11, 30]], "kind": "fixed"}])
    with Session(d) as s:
        model = s.model
        assert model.slaved.sum() > 0 and model.fixed.sum() > 0
        assert not np.any(model.fixed[:model.n_owned] & model.slaved)


def test_sensitivities_with_rigid_bones_match_finite_differences():
    """IK's marker Jacobian (forward and adjoint) through the bordered solve, a marker in silicone and one
    in a rigid bone, against central differences of solves."""
    from skelfem.analysis.sensitivity import Linearization
    d = _rigid_strip()
    d["markers"]["bone"] = [5.0, 40.0]
    with Session(d) as s:
        r = s.solve()
        names = list(r.markers)
        lin = Linearization(s.model, s.solver)
        J = {n: (lin.marker_jacobian(i, "forward"), lin.marker_jacobian(i, "adjoint")) for i, n in enumerate(names)}
        lin.destroy()
        h, pos = 1e-4, {}
        for sign in (1, -1):
            s.set({"cables.flexor.contraction": 3.0 + sign * h})
            pos[sign] = s.solve().markers
    for n in names:
        fd = (np.array(pos[1][n]["position"]) - np.array(pos[-1][n]["position"])) / (2 * h)
        for Jn in J[n]:
            assert np.allclose(Jn.ravel(), fd, rtol=1e-5, atol=1e-7), (n, Jn, fd)
    assert np.linalg.norm(J["bone"][0]) > 0.1


def test_dynamics_with_rigid_bones_approach_stiff_elastic_bones():
    tips = []
    for rigid, E in ((True, None), (False, 1e4), (False, 1e5)):
        d = _rigid_strip(rigid=rigid, E_bone=E)
        d["materials"]["soft"]["density"], d["materials"]["hard"]["density"] = 1100.0, 1200.0
        d["dynamics"] = {"dt": 0.005, "duration": 0.03, "integrator": "bdf2"}
        with Session(d) as s:
            r = s.run_in_time()
            assert r.converged
            if rigid:
                assert _rigid_deviation(s.model) <= 1e-12 * s.model.size
            tips.append(np.array(r.markers["tip"]["position"]))
    d4, d5 = (np.linalg.norm(t - tips[0]) for t in tips[1:])
    assert 5 < d4 / d5 < 20                           # about 1/E_bone


@pytest.mark.mpi
def test_rigid_bones_serial_equals_two_ranks(tmp_path, mpirun):
    import json
    import sys
    script = tmp_path / "run.py"
    script.write_text(
        "import json, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from mpi4py import MPI\nfrom skelfem import Session\nimport test_rigid_bones as t\n"
        "with Session(t._rigid_strip()) as s:\n"
        "    r = s.solve()\n"
        "    dev = MPI.COMM_WORLD.allreduce(t._rigid_deviation(s.model), op=MPI.MAX)\n"
        "    if MPI.COMM_WORLD.rank == 0:\n"
        "        print(json.dumps([r.markers['tip']['position'], r.bones['b2']['rotation'], dev]))\n")
    with Session(_rigid_strip()) as s:
        r = s.solve()
    proc = mpirun.run([sys.executable, script], ranks=2, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    tip, rot, dev = json.loads(proc.stdout.strip().splitlines()[-1])
    assert np.allclose(tip, r.markers["tip"]["position"], rtol=0, atol=1e-8)
    assert rot == pytest.approx(r.bones["b2"]["rotation"], abs=1e-10)
    assert dev <= 1e-12 * 100


def test_rigid_bones_in_3d():
    """6 rigid DOFs per bone: finger3d converges with exactly rigid bones, near its elastic-bone tip."""
    bones = ("proximal", "middle", "distal")
    tips = {}
    for rigid in (False, True):
        with Session(GEOMETRY / "finger3d.toml", ["mesh.size=6"] + [f"bones.{b}.rigid={str(rigid).lower()}"
                                                                   for b in bones]) as s:
            r = s.solve()
            assert r.converged
            tips[rigid] = np.array(r.markers["tip"]["position"])
            if rigid:
                assert all(b.m == 6 for b in s.model.rigid)
                assert _rigid_deviation(s.model) <= 1e-12 * s.model.size
                assert len(r.bones["distal"]["rotation"]) == 3
    assert np.linalg.norm(tips[True] - tips[False]) < 0.05


def test_assembling_with_rigid_bones_does_not_leak():
    """Each Newton matrix with rigid bones takes K T (a PETSc sparse-dense product) for the border; the
    product used to be left to the garbage collector, which petsc4py 3.18 parks until a collective
    clean-up: K T and T leaked per assembly (7.5 MB a Newton step on arm3d at 19k DOFs)."""
    import gc

    def rss_mb() -> float:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024
    rigid = [f"bones.{b}.rigid=true" for b in ("proximal", "middle", "distal")]
    with Session(GEOMETRY / "finger3d.toml", overrides=["mesh.size=4"] + rigid) as s:
        assert s.solve().converged
        model, solver = s.model, s.solver
        T = model.border.T
        for _ in range(5):
            solver.assemble(solver.x)
        gc.collect()
        r0 = rss_mb()
        for _ in range(30):
            solver.assemble(solver.x)
        gc.collect()
        grown = rss_mb() - r0
    leak = 30 * 2 * T.nbytes / 2**20             # what K T and T per assembly would have cost
    assert leak > 20 and grown < 0.15 * leak, (grown, leak)

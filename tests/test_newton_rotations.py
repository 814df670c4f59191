"""Newton on slender soft bodies that rotate a lot: the elastica and a strip curled by a tendon.

The default globalisation (line_search = "auto": "curved" for bodies without
bones) must converge in few iterations from rest at full load, with default
settings, and be as accurate as the mesh: the cantilever's tip against the
exact elastica (shooting on theta'' = -alpha cos(theta)), the curled strip's
curvature against the exact bending of a Neo-Hookean section under the
tendon's force, and against T d / (E'I) where the tendon compresses the strip
little. The iteration counts the user pays include the iterations of cut
attempts.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, fsolve

from skelfem import Session
from skelfem.terms.elasticity import lame

E, NU, THICK = 1.0, 0.3, 10.0
E_PLANE = E / (1.0 - NU ** 2)          # plane strain: E' = E / (1 - nu^2)


def elastica_tip(alpha: float) -> np.ndarray:
    """Tip displacement / L of a clamped cantilever under a dead transverse tip load, P L^2 / (E'I) = alpha.

    theta(s) (s = arc length / L) solves theta'' = -alpha cos(theta),
    theta(0) = 0, theta'(1) = 0 (no moment at the tip); shooting on
    theta'(0) in [0, alpha]. Returns (x(1) - 1, -y(1)) with x' = cos, y' = sin.
    """
    def rhs(s, z):
        th, dth, x, y = z
        return [dth, -alpha * np.cos(th), np.cos(th), np.sin(th)]

    def end(k):
        return solve_ivp(rhs, (0.0, 1.0), [0.0, k, 0.0, 0.0], rtol=1e-12, atol=1e-12).y[:, -1]

    k = brentq(lambda k: end(k)[1], 0.0, alpha, xtol=1e-14)
    _, _, x, y = end(k)
    return np.array([x - 1.0, -y])


def test_shooting_reference_small_load():
    # linear beam theory for small alpha: deflection alpha / 3, shortening ~ (2/15) alpha^2 / ... (second order)
    tip = elastica_tip(1e-3)
    assert tip[1] == pytest.approx(-1e-3 / 3.0, rel=1e-3)
    assert abs(tip[0]) < 1e-6
    # a tabulated point of the elastica (Bisshopp & Drucker 1945): alpha = 1: deflection 0.3017 L
    assert elastica_tip(1.0)[1] == pytest.approx(-0.3017, abs=2e-4)


def section_curvature(T: float, d: float, h: float, E: float = E, nu: float = NU, t: float = THICK) -> float:
    """Curvature (1 / deformed radius) of the axis of a plane-strain Neo-Hookean strip of
    thickness h bent by a tendon of tension T at d from the axis: finite-strain pure bending.

    Away from the clamp and the tendon's end the strip is an annular sector: the material
    line at Y (Y in [-h/2, h/2] across the strip, the tendon at Y = d) becomes an arc of
    radius r(Y) about the centre, the sections stay radial, and with theta' the turn per
    reference length the stretches are lambda_1 = r theta' (along), lambda_2 = -r'(Y)
    (across), 1 (out of plane). For psi of skelfem.terms.elasticity the nominal stresses are
    P_i = mu (lambda_i - 1/lambda_i) + lam ln(J) / lambda_i, J = lambda_1 lambda_2, and the
    Cauchy stresses sigma_theta = P_1 / lambda_2, sigma_r = P_2 / lambda_1. Radial equilibrium,

        d sigma_r / dr = (sigma_theta - sigma_r) / r,   i.e.  sigma_r' = -lambda_2 (sigma_theta - sigma_r) / r,

    fixes lambda_2 at each Y (from P_2 = lambda_1 sigma_r); the tendon presses on its line
    with T per radian, so sigma_r drops by T / (t r(d)) across Y = d; sigma_r = 0 on both
    faces. The section carries the tendon's pull: the axial force t int P_1 dY = -T, with
    no moment about the tendon, int P_1 (r - r(d)) dY = 0. Shooting from the outer face
    Y = -h/2 on (theta', lambda_1 there) meets both; returns 1 / r(0). For small T it is
    T d / (E'I), E' = E / (1 - nu^2), I = t h^3 / 12.
    """
    mu, lam = lame(E, nu)

    def across(l1, sr):
        """lambda_2 with P_2(lambda_1, lambda_2) = lambda_1 sigma_r (Newton)."""
        l2 = 1.0
        for _ in range(50):
            step = (mu * (l2 * l2 - 1) + lam * np.log(l1 * l2) - l1 * l2 * sr) / (2 * mu * l2 + lam / l2 - l1 * sr)
            l2 -= step
            if abs(step) < 1e-13:
                return l2
        raise RuntimeError("no transverse stretch")

    def rhs(Y, z, k):
        r, sr = z[:2]
        l1 = r * k
        l2 = across(l1, sr)
        P1 = mu * (l1 - 1 / l1) + lam * np.log(l1 * l2) / l1
        return [-l2, -l2 * (P1 / l2 - sr) / r, P1, P1 * r]      # r, sigma_r, int P_1, int P_1 r

    def shoot(x):
        k, l1_out = x
        z, radii = np.array([l1_out / k, 0.0, 0.0, 0.0]), []
        for a, b in ((-h / 2, 0.0), (0.0, d), (d, h / 2)):
            z = solve_ivp(rhs, (a, b), z, args=(k,), method="DOP853", rtol=1e-11, atol=1e-13).y[:, -1]
            radii.append(z[0])
            if b == d:
                z[1] -= T / (t * z[0])
        return z, radii[0], radii[1]

    def residual(x):
        z, _, r_d = shoot(x)
        return [t * z[2] / T + 1.0, t * (z[3] - r_d * z[2]) / (T * h)]

    k_lin = T * d / (E / (1 - nu ** 2) * t * h ** 3 / 12)
    x, _, ok, msg = fsolve(residual, [k_lin, 1 + k_lin * h / 2], xtol=1e-12, full_output=True)
    assert ok == 1, msg
    return 1.0 / shoot(x)[1]


def test_section_reference_small_curvature():
    h, d = 4.0, 1.2
    k_lin = lambda T: T * d / (E_PLANE * THICK * h ** 3 / 12)
    assert section_curvature(1e-4, d, h) == pytest.approx(k_lin(1e-4), rel=1e-5)
    # the axial strain T / (E'A) lowers the curvature below the linear formula, about in proportion
    low = [1 - section_curvature(T, d, h) / k_lin(T) for T in (0.4, 0.8)]
    assert 0.005 < low[0] < 0.015 and low[1] == pytest.approx(2 * low[0], rel=0.1)


def elastica_design(alpha, L=120.0, h=3.0, size=0.75, degree=2, **solver):
    I = THICK * h ** 3 / 12.0
    P = alpha * E_PLANE * I / L ** 2
    return {"format": 1, "name": "elastica", "dim": 2, "thickness": THICK,
            "mesh": {"size": size, "degree": degree},
            "materials": {"soft": {"E": E, "nu": NU}},
            "body": {"outline": [[0, 0], [L, 0], [L, h], [0, h]], "material": "soft"},
            "pins": [{"name": "base", "region": [[-1, -1], [1e-6, h + 1]], "kind": "fixed"}],
            "loads": [{"name": "tip", "at": [L, h / 2], "force": [0.0, -P]}],
            "markers": {"tip": [L, h / 2]},
            "solver": dict(solver)}


def curl_design(contraction=7.3, L=100.0, h=4.0, d=1.2, k=100.0, size=0.5, degree=2, **solver):
    """A strip clamped at y = 0, a tendon at d from its axis; markers along the axis.

    The tendon bends the strip (kappa L d = pi d for half a circle) and
    compresses it (kappa h^2 L / (12 d)): 7.3 mm curl it to about half a circle."""
    markers = {f"m{i}": [h / 2, L * i / 10] for i in range(1, 11)}
    return {"format": 1, "name": "curl", "dim": 2, "thickness": THICK,
            "mesh": {"size": size, "degree": degree},
            "materials": {"soft": {"E": E, "nu": NU}},
            "body": {"outline": [[0, 0], [h, 0], [h, L], [0, L]], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[h / 2 + d, 0], [h / 2 + d, L]],
                        "stiffness": k, "contraction": contraction}],
            "pins": [{"name": "base", "region": [[-1, -1], [h + 1, 1e-6]], "kind": "fixed"}],
            "markers": markers,
            "solver": dict(solver)}


def _circle_curvature(points: np.ndarray) -> float:
    """1 / radius of the least-squares circle through points (Kasa fit)."""
    x, y = points[:, 0], points[:, 1]
    A = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    cx, cy, c = np.linalg.lstsq(A, x ** 2 + y ** 2, rcond=None)[0]
    return 1.0 / np.sqrt(c + cx ** 2 + cy ** 2)


def _solve(design):
    with Session(design) as s:
        return s.solve()


@pytest.mark.slow
@pytest.mark.parametrize("alpha, cap", [(1.0, 15), (3.0, 25), (10.0, 25)])
def test_elastica_tip_and_iterations(alpha, cap):
    L, h = 120.0, 3.0
    r = _solve(elastica_design(alpha))
    assert r.converged
    tip = (np.asarray(r.markers["tip"]["position"]) - [L, h / 2]) / L
    ref = elastica_tip(alpha)
    assert np.linalg.norm(tip - ref) <= 0.01 * np.linalg.norm(ref), (tip, ref)
    assert r.newton_iterations <= cap
    assert r.newton_iterations == sum(a["iterations"] for a in r.attempts)


@pytest.mark.slow
@pytest.mark.parametrize("contraction, h, turn, linear, cap", [(0.5 * np.pi * 1.2, 4.0, 0.125, True, 40),
                                                              (7.3, 4.0, 0.5, False, 40),
                                                              (5.75, 3.0, 0.5, True, 40)])
def test_curl_curvature_and_iterations(contraction, h, turn, linear, cap):
    """turn: the fraction of a circle; cap: Newton iterations (40 on both strips).
    The curvature matches the section's finite-strain bending (section_curvature) to the mesh's
    accuracy; T d / (E'I) only where the tendon compresses the strip little: at half a circle it
    compresses the 4 mm strip by T / (E'A) = 3.7 % and the curvature is 4.3 % below the linear
    formula, the 3 mm strip by 2 % and 1.6 % below."""
    L, d = 100.0, 1.2
    r = _solve(curl_design(contraction, L=L, h=h, d=d))
    assert r.converged
    if cap is not None:
        assert r.newton_iterations <= cap
    T = r.cables["flexor"]["tension"]
    # the middle of the strip (away from the clamp and the tendon's end)
    pts = np.array([r.markers[f"m{i}"]["position"] for i in range(2, 9)])
    kappa = _circle_curvature(pts)
    assert kappa == pytest.approx(section_curvature(T, d, h), rel=1e-3)
    if linear:
        assert kappa == pytest.approx(T * d / (E_PLANE * THICK * h ** 3 / 12.0), rel=0.03)
    assert kappa * L / (2 * np.pi) == pytest.approx(turn, rel=0.15)


@pytest.mark.slow
@pytest.mark.parametrize("options", [{"Mesh.Smoothing": 5}, {"Mesh.Algorithm": 5},
                                     {"Mesh.Algorithm": 1, "Mesh.Smoothing": 3}],
                         ids=["frontal-smoothed", "delaunay", "meshadapt-smoothed"])
@pytest.mark.parametrize("h, contraction", [(3.0, 5.75), (4.0, 7.3)])
def test_the_half_circle_curl_takes_at_most_40_iterations_on_other_meshes(monkeypatch, options, h, contraction):
    """The line search must not depend on how the triangles were made: the same strips meshed with
    Laplacian smoothing and by other Gmsh algorithms than skelfem's own (frontal-Delaunay, unsmoothed,
    in the test above) converge from rest within the same 40 iterations."""
    import gmsh
    set_number = gmsh.option.setNumber

    def with_options(name, value):
        set_number(name, value)
        if name == "Mesh.Smoothing":        # the last of skelfem's meshing options: override after it
            for k, v in options.items():
                set_number(k, v)
    plain = _solve(curl_design(contraction, h=h, size=0.5))
    monkeypatch.setattr(gmsh.option, "setNumber", with_options)
    r = _solve(curl_design(contraction, h=h, size=0.5))
    assert (r.dofs, r.cells, r.min_jacobian) != (plain.dofs, plain.cells, plain.min_jacobian)   # another mesh
    assert r.converged and r.newton_iterations <= 40, r.newton_iterations
    kappa = _circle_curvature(np.array([r.markers[f"m{i}"]["position"] for i in range(2, 9)]))
    assert kappa * 100.0 / (2 * np.pi) == pytest.approx(0.5, rel=0.15)


def test_auto_is_curved_without_bones_and_energy_with():
    from skelfem.fem.newton import resolve_strategy
    from skelfem.session import as_design
    from conftest import GEOMETRY
    assert resolve_strategy(as_design(elastica_design(1.0))) == "curved"
    assert resolve_strategy(as_design(GEOMETRY / "finger.toml")) == "energy"


def test_cut_attempts_are_counted():
    # a monotone line search with a tight iteration cap: the full-load attempt fails, is cut and retried
    r = _solve(elastica_design(1.0, size=1.5, degree=1, line_search="energy", max_iterations=6))
    failed = [a for a in r.attempts if a["status"] != "converged"]
    assert failed and failed[0]["iterations"] == 6
    assert r.newton_iterations == sum(a["iterations"] for a in r.attempts)
    assert r.newton_iterations > sum(a["iterations"] for a in r.attempts if a["status"] == "converged")


@pytest.mark.slow
@pytest.mark.parametrize("contraction, L, h, d, size", [(14.6, 100.0, 4.0, 1.2, 0.6), (14.6, 100.0, 4.0, 1.0, 0.6),
                                                         (20.0, 120.0, 5.0, 1.2, 0.6)],
                         ids=["coil", "closer-tendon", "longer-thicker"])
def test_a_full_circle_coil_takes_at_most_40_iterations(contraction, L, h, d, size):
    """A strip coiled by its tendon through a full circle or more, from rest in one load step: the curved
    search's steps turn it at most 0.5 rad each (at 1 rad the first two took 152 and 161 iterations in five
    and six attempts; the third converged either way)."""
    r = _solve(curl_design(contraction, L=L, h=h, d=d, size=size))
    assert r.converged and r.newton_iterations <= 40, (r.newton_iterations, r.attempts)
    assert len(r.attempts) == 1
    pts = np.array([r.markers[f"m{i}"]["position"] for i in range(2, 9)])
    assert _circle_curvature(pts) * L / (2 * np.pi) >= 0.95          # at least a full circle


def sliding_block_design(k: float = 100.0, theta: float = 20.0, L: float = 20.0, H: float = 5.0) -> dict:
    """A soft L x H block (E = 100 kPa) on a frictionless floor of penalty stiffness k under gravity tilted
    by theta, held back by a spring pin on its uphill end (2e-5 N/mm per mm^2 of its end face): it slides by
    W sin(theta) / (2e-5 H t) (studies/friction_stability.py's block on a slope, mu = 0)."""
    th = np.radians(theta)
    return {"format": 1, "name": "block", "dim": 2, "thickness": THICK, "mesh": {"size": 1.0, "degree": 1},
            "materials": {"m": {"E": 0.1, "nu": 0.3, "density": 1e4}},
            "body": {"outline": [[0, 0], [L, 0], [L, H], [0, H]], "material": "m"},
            "pins": [{"name": "pull", "region": [[L - 0.1, -1], [L + 1, H + 1]], "kind": "spring",
                      "stiffness": 1e-3 / 50.0}],
            "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": k}],
            "gravity": {"acceleration": [-9.81 * np.sin(th), -9.81 * np.cos(th)]},
            "markers": {"c": [L / 2, H / 2]}, "solver": {"line_search": "curved"}}


@pytest.mark.parametrize("k, theta, L, H", [(100.0, 20.0, 20.0, 5.0), (100.0, 10.0, 40.0, 4.0)])
def test_the_watchdog_goes_back_to_its_reference_when_its_steps_stall(k, theta, L, H):
    """From rest the floor does not hold the block yet (its penalty is zero at zero depth): the first Newton
    step sinks it and raises Pi from 0 to 2e5 N mm, a relaxed step the watchdog takes. The Armijo steps after
    it each lower Pi but stay far above the reference, the later ones closing a few percent of the gap each;
    counting only relaxed steps, the watchdog never went back, and every attempt ended at its 50 iterations
    (450 in all, each step capped by the rotation limit in the sunk block). Counting the steps that close
    less than a tenth of the gap too, Newton returns to the reference and converges in about 20."""
    r = _solve(sliding_block_design(k, theta, L, H))
    assert r.converged and len(r.attempts) == 1 and r.newton_iterations <= 30, (r.newton_iterations, r.attempts)
    W = 1e4 * 1e-9 * 9.81 * L * H * THICK
    slid = L / 2 - r.markers["c"]["position"][0]
    assert slid == pytest.approx(W * np.sin(np.radians(theta)) / (1e-3 / 50.0 * H * THICK), rel=0.02)

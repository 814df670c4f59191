"""Cable friction along one cable: how the tension varies from segment to segment (capstan).

A cable with friction is a chain of m segments between its via points. Its
material slides through the interior via points j = 1..m-1; ``s_j`` is the
length of cable material that has passed through via point j towards the
actuated end (the first path point) since rest. Segment i holds the material

    L_i = L0_i + s_{i+1} - s_i,      s_0 = a u_c (pulled out by the actuator), s_m = 0,

with L0_i the segment's length at rest, and carries the tension
T_i = max(l_i - L_i, 0) / c_i, l_i its current length, c_i = L0_i / (k L0) its
compliance (the cable's compliance 1/k shared by length, so that a uniform
tension gives back the frictionless spring T = k (l - L)).

Coulomb friction at via point j, where the cable turns by the angle theta_j,
acts on the resultant of the two tensions: the normal force is
N_j = (T_{j-1} + T_j) sin(theta_j / 2) and the tangential one
(T_{j-1} - T_j) cos(theta_j / 2), so the via point holds the material while

    |T_{j-1} - T_j| <= F_j = mu tan(theta_j / 2) (T_{j-1} + T_j)       (1)

and lets it slip towards the higher tension at the limit. Equivalently
T_hi / T_lo <= (1 + mu tan(theta/2)) / (1 - mu tan(theta/2)); n such via
points along an arc of total angle Theta give e^(mu Theta) + O(n^-2) in the
log (the capstan equation), and a bend with mu tan(theta / 2) >= 1 locks.

**Within a load step** the slips are measured from the anchors s^ of the last
accepted state, lambda_j = s_j - s^_j, and the friction limits F_j are
lagged (held fixed while Newton solves). The cable's energy is then the
incremental potential

    Psi(u) = min_lambda  sum_i Q(b_i + lambda_i - lambda_{i+1}) / c_i + sum_j F_j |lambda_j|,

b_i = l_i(u) - L^_i the segment's stretch if every via point stuck (Q(x) =
x^2/2 for x > 0, else 0). Its dual is a projection of the stick tensions
b_i / c_i onto the tensions that (1) admits:

    Psi(u) = max_T { sum_i T_i b_i - c_i T_i^2 / 2 :  T_i >= 0,  |T_j - T_{j-1}| <= F_j },

solved exactly by :func:`tensions`. By
the envelope theorem grad Psi = sum_i T_i grad l_i: each segment pulls on its
two via points with its own tension. The Hessian is sum_i T_i hess l_i plus,
for every *zone* (a run of segments joined by slipping via points, all taut),
the rank-one part g_z g_z^T / C_z, g_z = sum_{i in z} grad l_i and C_z =
sum_{i in z} c_i: within a zone the tensions differ by the fixed F_j and
share one unknown level. A sticking via point separates zones; a frictionless
cable is one zone, the spring k g g^T of the frictionless model.

The lag is iterated to the fixed point F_j = mu tan(theta_j/2)(T_{j-1} + T_j)
of (1) (:func:`coulomb_limits`, at the geometry of a converged state; then
Newton again), so the converged state satisfies Coulomb's law with the
normal force of that state. After the step the anchors move by the slips
(:func:`slips`): a sticking via point keeps its material, so nothing creeps.

**The chain solve without a loop along the chain.** The dual is strictly concave, so its maximiser is
unique, and for a given stick/slip pattern (which via points slip, which way) its taut tensions are
closed-form: T = tau_z + offsets in each zone, tau_z from the zone's material balance, and the slips
are cumulative sums of the excess stretches (:func:`pattern_tensions`, whole-chain array operations).
:func:`chain_solve` starts from the pattern of the cable's last solve, which Newton's next iterate and
the next round rarely change, and updates it by a primal-dual active-set step (a semi-smooth Newton
step on the complementarity: a sticking via point past its limit slips, a slipping one whose slip has
the wrong sign sticks) until the optimality conditions hold, which certifies the answer; a chain it
does not settle in a few passes, or whose optimum has slack segments, goes to the dynamic programme
(:func:`chain_programme`, exact, a loop along the chain).

**Why the limits stay lagged.** Written with F_j = mu tan(theta_j/2)(T_{j-1} + T_j) inside the
projection (a cone in T at fixed geometry), the maximiser is another model: in a slipping zone its
level is sum w_i b_i / sum c_i w_i^2 (w the zone's tension profile), not the material balance
sum b_i / sum c_i w_i, so material would not be conserved through the via points; and Coulomb friction
whose normal force follows the state has no potential (its tangent is not symmetric), while Newton's
line search and its low-rank solve need an energy and symmetric rank-one parts. The lag keeps an exact
potential per round; :func:`coulomb_limits` gives the limits that hold with their own tensions at the
round's geometry.

**What the rounds cost, and why they converge.** The rounds are a fixed-point iteration F <- G(F), G the
limits at the equilibrium of the lagged problem with limits F, accelerated by Anderson mixing
(:func:`anderson`); each round is a warm Newton solve stopped at 1e-2 of its own first residual while the
limits move (the first of a load step too, Lagged.lags_follow_the_step; not a time step's: flick.toml at mu
0.3 took 3,509 Newton iterations so, against 2,395), and one tight solve once they hold. An inexact solve
whose error is a fixed fraction of the lags' change converges as the exact iteration does (its error shrinks
with the change, as the forcing term of an inexact Newton method); the rounds end with the same test as
tight ones (no F_j moves by more than LAG_RTOL of the largest tension at a fully solved state), so answers
agree to that tolerance (tip and tensions within 5e-5 relative on the bundled fingers against tight first
solves). On finger_knuckles (mu 0.3) a step is a first solve of about the frictionless iterations and 5-8
rounds of 1-2 iterations while the limits converge (a factor of about 30 per round). Measured and not kept:
limits updated at every Newton iteration (F = G(u) at each iterate, the lagged Hessian as tangent: steps up
9-13 iterations where the rounds take 7-8, and the reversal failed), limits taken at the predicted state of
a step (finger_knuckles 88 -> 262 iterations), extrapolated along the load path (88 -> 83), a round's first
step with the previous K (88 -> 99), a round stopped when |R| stalls (the reversal 62 -> 70). A load
reversal and a run in time stay dear for another reason: the first solve of the step is the one that takes
the iterations (50 and more on the finger's first step down), as Newton's iterates first let the released
cable go slack (its tensions fixed by the old limits: no stiffness) and then change which via points slip,
and which way, a few at a time, with short line-search steps (a semi-smooth Newton iteration far from its
solution); the lagged problem itself is benign there (from the answer, 2 iterations).
"""
from __future__ import annotations

import numpy as np

LOCKED = np.inf      # the friction limit of a bend that locks (mu tan(theta / 2) >= 1)


ACTIVE_SET_PASSES = 12    # pattern updates the vectorised chain solve tries before the dynamic programme
KKT_RTOL = 1e-12          # the optimality certificate's tolerance, relative to the largest tension / stretch


def tensions(b: np.ndarray, c: np.ndarray, F: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
    """The segment tensions T maximising sum T b - c T^2 / 2 subject to T >= 0 and
    |T_j - T_{j-1}| <= F_{j-1} (F: one limit per interior via point, len(b) - 1 of them).

    The problem is strictly concave, so its maximiser is unique: :func:`chain_solve` finds it by
    whole-chain (vectorised) passes over stick/slip patterns and certifies it; a chain whose pattern
    it does not settle (or whose optimum has slack segments) goes to the dynamic programme
    :func:`chain_programme`. ``guess``: a pattern to start from (a previous solve's, :func:`pattern`)."""
    return chain_solve(b, c, F, guess)[0]


def chain_solve(b: np.ndarray, c: np.ndarray, F: np.ndarray,
                guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(T, pattern) of :func:`tensions`. A pattern s gives each interior via point 0 (it sticks) or the
    sign of T_{j-1} - T_j at its limit (it slips); for a pattern, the taut tensions are closed-form
    (:func:`pattern_tensions`). A primal-dual active-set iteration (a semi-smooth Newton step on the
    complementarity |T_{j-1} - T_j| <= F_j, slip = 0 below the limit) moves a sticking via point past
    its limit to slipping and a slipping one whose slip has the wrong sign to sticking, until the
    Karush-Kuhn-Tucker conditions hold: then T is the maximiser."""
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    F = np.asarray(F, dtype=float)
    free, bound = np.isfinite(F), F == 0.0               # a zero limit joins its segments, either way
    if _all_slack(b, F):
        return np.zeros(len(b)), np.zeros(len(F))
    if guess is None or len(guess) != len(F):           # no pattern to start from: the exact programme
        T = chain_programme(b, c, F)
        return T, pattern(T, F)
    s = np.where(free, np.where(bound, 1.0, guess), 0.0)
    for _ in range(ACTIVE_SET_PASSES):
        T, lam = pattern_tensions(b, c, F, s)
        tol_T = KKT_RTOL * max(float(np.abs(T).max()), 1e-300)
        tol_lam = KKT_RTOL * max(float(np.abs(b).max()), float(np.abs(c * T).max()), 1e-300)
        d = T[:-1] - T[1:]
        over = (s == 0) & free & (np.abs(d) > F + tol_T)
        wrong = (s != 0) & ~bound & (s * lam < -tol_lam)
        if not over.any() and not wrong.any():
            if T.min() >= -tol_T:
                return np.maximum(T, 0.0), s
            break                                          # slack segments: the dynamic programme
        s = np.where(over, np.sign(d), np.where(wrong, 0.0, s))
    T = chain_programme(b, c, F)
    return T, pattern(T, F)


def _all_slack(b: np.ndarray, F: np.ndarray) -> bool:
    """Whether T = 0 is the maximiser: no feasible direction T >= 0 raises sum T b, i.e. every run of
    segments joined by zero limits has sum b <= 0."""
    label = np.concatenate(([0], np.cumsum(F != 0.0)))
    return bool(np.all(np.bincount(label, weights=b) <= 0.0))


def pattern(T: np.ndarray, F: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """The stick/slip pattern of tensions T: the sign of T_{j-1} - T_j at a via point at its limit, else 0."""
    scale = max(float(T.max()) if len(T) else 0.0, 1e-300)
    d = T[:-1] - T[1:]
    return np.where(np.isfinite(F) & (np.abs(d) >= F - rtol * scale), np.sign(d), 0.0)


def pattern_tensions(b: np.ndarray, c: np.ndarray, F: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, slips) of the pattern s with every segment taut: a zone (segments joined by slipping via
    points) has T_i = tau_z + o_i, the offsets o stepping by -s_j F_j across its via points, and its
    level tau_z from its material balance sum c_i T_i = sum b_i; the slip through via point j is the
    excess stretch b_i - c_i T_i summed over the zone's segments before it. Vectorised along the chain."""
    m = len(b)
    joined = s != 0
    step = np.where(joined, -s * np.where(joined, F, 0.0), 0.0)
    o = np.concatenate(([0.0], np.cumsum(step)))
    start = np.concatenate(([True], ~joined))
    base = np.maximum.accumulate(np.where(start, np.arange(m), 0))      # each segment's zone start
    o = o - o[base]
    label = np.cumsum(start) - 1
    tau = (np.bincount(label, weights=b) - np.bincount(label, weights=c * o)) / np.bincount(label, weights=c)
    T = tau[label] + o
    cs = np.concatenate(([0.0], np.cumsum(b - c * T)))
    lam = np.where(joined, cs[1:m] - cs[base[:-1]], 0.0)
    return T, lam


def chain_programme(b: np.ndarray, c: np.ndarray, F: np.ndarray) -> np.ndarray:
    """:func:`tensions` by dynamic programming along the chain: H_i(T) is the least value of
    sum_{k<=i} (c_k T_k^2 / 2 - b_k T_k) with T_i = T; its derivative is a
    non-decreasing piecewise-linear function of T >= 0 (knots x, values v, slope
    beyond the last knot), and H_i = f_i + (H_{i-1} minimised over a window of
    half-width F_i): the window shifts the part of H' left of its zero by -F and
    the part right of it by +F, with H' = 0 in between. Backtracking then takes
    T_{i-1} = clip(argmin H_{i-1}, T_i - F_i, T_i + F_i).
    """
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    m = len(b)
    x, v, slope = np.zeros(1), np.array([-b[0]]), c[0]
    best = np.empty(m)
    for i in range(1, m + 1):
        t = _zero(x, v, slope)
        best[i - 1] = t
        if i == m:
            break
        f = F[i - 1]
        if not np.isfinite(f):                       # a locked bend: the segments decouple
            x, v, slope = np.zeros(1), np.zeros(1), 0.0
        else:
            left = v < 0.0                           # a prefix: H' is non-decreasing
            x = np.concatenate((x[left] - f, [t - f, t + f], x[~left] + f))
            v = np.concatenate((v[left], [0.0, 0.0], v[~left]))
            keep = x >= 0.0
            if not keep.all():
                first = int(np.argmax(keep)) if keep.any() else len(x)
                if first == len(x):                  # every knot left of 0: the last piece continues
                    v0 = v[-1] - slope * x[-1]
                else:
                    x0, x1, v_0, v_1 = x[first - 1], x[first], v[first - 1], v[first]
                    v0 = v_1 if x1 == x0 else v_0 + (v_1 - v_0) * (0.0 - x0) / (x1 - x0)
                x, v = np.concatenate(([0.0], x[keep])), np.concatenate(([v0], v[keep]))
        v = v + c[i] * x - b[i]
        slope = slope + c[i]
    T = np.empty(m)
    T[-1] = best[-1]
    for i in range(m - 1, 0, -1):
        f = F[i - 1]
        T[i - 1] = best[i - 1] if not np.isfinite(f) else min(max(best[i - 1], T[i] - f), T[i] + f)
    return np.maximum(T, 0.0)


def _zero(x: np.ndarray, v: np.ndarray, slope: float) -> float:
    """Where the non-decreasing piecewise-linear H' (knots x, values v, then slope) crosses zero (>= 0)."""
    if v[0] >= 0.0:
        return 0.0
    k = int(np.searchsorted(v, 0.0, side="left")) - 1      # the last knot with v < 0
    if k == len(v) - 1:
        return float(x[-1] - v[-1] / slope) if slope > 0.0 else np.inf
    if x[k + 1] == x[k]:
        return float(x[k])
    return float(x[k] - v[k] * (x[k + 1] - x[k]) / (v[k + 1] - v[k]))


def value(b: np.ndarray, c: np.ndarray, T: np.ndarray) -> float:
    """Psi = sum T b - c T^2 / 2 at the optimal tensions."""
    return float(T @ b - 0.5 * (c * T) @ T)


def zones(T: np.ndarray, F: np.ndarray, rtol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """(zone label per segment, taut flag per zone): segments joined by via points at their friction
    limit (slipping, or about to) share a zone; a zone with a slack segment (T = 0) has no stiffness
    (its tensions are fixed by the limits, not by its stretch)."""
    scale = max(float(T.max()) if len(T) else 0.0, 1e-300)
    joined = np.abs(np.diff(T)) >= F - rtol * scale
    label = np.concatenate(([0], np.cumsum(~joined)))
    slack = np.bincount(label, weights=(T <= rtol * scale).astype(float)) > 0
    return label, ~slack


def slips(b: np.ndarray, c: np.ndarray, T: np.ndarray, F: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """The material lambda_j that moved through each interior via point (towards the actuated end > 0)
    for the optimal tensions T: e_i = b_i + lambda_i - lambda_{i+1} with e_i = c_i T_i on a taut
    segment and e_i <= 0 on a slack one; lambda_j = 0 through a via point below its limit, and of the
    sign of T_{j-1} - T_j at it. In a taut zone the slips are the sums of its segments' excess
    stretches; where a zone has slack segments, whose material is not fixed by their tension, the
    least total slip that satisfies these (a small linear programme)."""
    m = len(b)
    lam = np.zeros(m + 1)
    label, taut_zone = zones(T, F, rtol)
    scale = max(float(T.max()) if m else 0.0, 1e-300)
    excess = b - c * T                                 # material a taut segment gives to its neighbours
    starts = np.flatnonzero(np.diff(np.concatenate(([-1], label))))
    ends = np.concatenate((starts[1:], [m])) - 1
    for z, (lo, hi) in enumerate(zip(starts, ends)):
        if hi == lo:
            continue
        if taut_zone[z]:
            lam[lo + 1:hi + 1] = np.cumsum(excess[lo:hi])
        else:
            lam[lo + 1:hi + 1] = _slack_slips(b[lo:hi + 1], excess[lo:hi + 1], T[lo:hi + 1] > rtol * scale,
                                              np.sign(np.round((T[lo:hi] - T[lo + 1:hi + 1]) / scale, 9)))
    return lam[1:m]


def _slack_slips(b, excess, taut, sign) -> np.ndarray:
    """Slips through the k - 1 interior via points of a zone of k segments, some slack: minimise
    sum |lambda| subject to lambda_i - lambda_{i+1} = -excess_i (taut), <= -b_i (slack), lambda of the
    given sign (0: either), lambda_0 = lambda_k = 0."""
    from scipy.optimize import linprog
    k = len(b)
    n = k - 1                                          # unknowns lambda_1..lambda_{k-1} as p - q, p, q >= 0
    D = np.zeros((k, n))                               # row i: lambda_i - lambda_{i+1}
    for i in range(k):
        if i >= 1:
            D[i, i - 1] = 1.0
        if i < n:
            D[i, i] = -1.0
    A = np.hstack((D, -D))
    bounds = [(0, None if s >= 0 else 0) for s in sign] + [(0, None if s <= 0 else 0) for s in sign]
    res = linprog(np.ones(2 * n), A_ub=A[~taut], b_ub=-b[~taut], A_eq=A[taut], b_eq=-excess[taut],
                  bounds=bounds, method="highs")
    if res.status != 0:                                # round-off at a degenerate limit: keep the material
        return np.zeros(n)
    return res.x[:n] - res.x[n:]


def bend_tangents(t: np.ndarray) -> np.ndarray:
    """tan(theta_j / 2) at each interior via point, from the unit segment directions t (m, dim)."""
    a, b = t[:-1], t[1:]
    return np.linalg.norm(b - a, axis=1) / np.maximum(np.linalg.norm(b + a, axis=1), 1e-300)


def limits(mu_tan: np.ndarray, T: np.ndarray) -> np.ndarray:
    """F_j = mu tan(theta_j / 2) (T_{j-1} + T_j); a bend with mu tan(theta/2) >= 1 locks."""
    return np.where(mu_tan >= 1.0, LOCKED, mu_tan * (T[:-1] + T[1:]))


def coulomb_limits(b: np.ndarray, c: np.ndarray, mu_tan: np.ndarray, F: np.ndarray,
                   rtol: float = 1e-12, max_iterations: int = 200,
                   guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The fixed point F = limits(mu_tan, tensions(b, c, F)) at fixed stretches b, from F: the limits
    whose lagged solve satisfies (1) with its own tensions (each chain solve starts from the last one's
    pattern, or from ``guess``). Returns (F, T)."""
    F = np.array(F, dtype=float)
    T, s = chain_solve(b, c, F, guess)
    for _ in range(max_iterations):
        F_new = limits(mu_tan, T)
        scale = max(float(T.max()), 1e-300)
        finite = np.isfinite(F_new)
        done = np.array_equal(~finite, ~np.isfinite(F)) and \
            (not finite.any() or float(np.abs(F_new[finite] - F[finite]).max()) <= rtol * scale)
        F = F_new
        T, s = chain_solve(b, c, F, s)
        if done:
            break
    return F, T


def anderson(history: list) -> np.ndarray:
    """Anderson mixing for the fixed point F = G(F) from the pairs [(F_k, G_k)] (oldest first):
    G_k - sum_i gamma_i (G_i+1 - G_i) with gamma the least-squares fit of the residual differences,
    clipped to F >= 0. It mixes only the via points free (finite) in every F_k and G_k: a locked bend
    (LOCKED, infinite) has no residual to fit, and a pair from before a bend locked or unlocked would
    put inf - inf into the fit. One pair, or no usable fit: plain iteration, G_k."""
    _, G_k = history[-1]
    out = G_k.copy()
    free = np.logical_and.reduce([np.isfinite(f) & np.isfinite(g) for f, g in history])
    if len(history) < 2 or not free.any():
        return out
    R = np.array([g[free] - f[free] for f, g in history])
    Gs = np.array([g[free] for _, g in history])
    dR, dG = np.diff(R, axis=0).T, np.diff(Gs, axis=0).T
    try:
        gamma = np.linalg.lstsq(dR, R[-1], rcond=1e-10)[0]
    except np.linalg.LinAlgError:                      # round-off beyond repair: fall back on G_k
        return out
    mixed = Gs[-1] - dG @ gamma
    if np.all(np.isfinite(mixed)):
        out[free] = np.maximum(mixed, 0.0)
    return out


def restarted(history: list) -> list:
    """The mixing's history from its last pair alone if that round is further from the fixed point
    (larger max |G - F| over the free via points) than the one before: the mixing made it worse."""
    def residual(pair):
        F, G = pair
        free = np.isfinite(F) & np.isfinite(G)
        return float(np.abs(G[free] - F[free]).max()) if free.any() else 0.0
    if len(history) > 1 and residual(history[-1]) > residual(history[-2]):
        return history[-1:]
    return history


def frozen_limits(b: np.ndarray, c: np.ndarray, mu_tan: np.ndarray, T: np.ndarray, F: np.ndarray,
                  iterations: int = 500) -> np.ndarray:
    """The fixed point F_j = mu tan(theta_j/2)(T_j + T_j+1) with the stick/slip pattern of the tensions T
    (limits F) held: in each taut zone T_i = tau_z + o_i, the offsets o stepping by -s_j F_j across its
    slipping via points (s_j the sign of the slip), tau_z from the zone's material balance; slack zones
    carry nothing; sticking via points keep F_j. Smooth in b and mu_tan (the derivative of the
    equilibrium along the branch it is on); plain iteration, converging as the capstan's series."""
    label, taut = zones(T, F)
    joined = label[:-1] == label[1:]
    s = np.sign(T[:-1] - T[1:])
    C = np.bincount(label, weights=c)
    F = np.array(F, dtype=float)
    for _ in range(iterations):
        step = np.where(joined, -s * F, 0.0)
        o = np.concatenate(([0.0], np.cumsum(step)))
        start = np.concatenate(([True], ~joined))
        base = np.maximum.accumulate(np.where(start, np.arange(len(o)), 0))
        o = o - o[base]                                     # offsets from each zone's first segment
        tau = (np.bincount(label, weights=b) - np.bincount(label, weights=c * o)) / C
        Tz = np.where(taut[label], tau[label] + o, 0.0)
        new = np.where(joined, mu_tan * (Tz[:-1] + Tz[1:]), F)
        if np.abs(new - F).max() <= 1e-15 * max(float(np.abs(new).max()), 1e-300):
            return new
        F = new
    return F

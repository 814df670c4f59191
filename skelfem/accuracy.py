"""Model no more than the scene needs: mesh size and degree for a marker tolerance.

``skelfem simulate DESIGN --tol ABS_MM`` picks (degree p, size h) so that the
estimated marker position error stays below ABS_MM at the least predicted
cost. The models were fitted by ``studies/speed_accuracy.py`` on finger.toml
(tip motion U_ref = 46.3 mm) against a Richardson-checked P2 reference:

    error   e_p(h) = C_p (U / U_ref) h^r_p      C_1 = 0.50, r_1 = 0.99;  C_2 = 0.086, r_2 = 1.47
    cost    t_p(h) ~ T_p h^-q_p                  T_1 = 0.685, q_1 = 1.78;  T_2 = 3.16, q_2 = 2.14

U, the design's largest marker motion, comes from a cheap P2 solve at h = 4
(the error models scale with the motion). Each degree gets the coarsest h in
[H_MIN, H_MAX] with 2 e_p(h) <= tol; the cheaper one wins. P1 triangles lock
for nearly incompressible materials, so nu > 0.49 forces P2.

Limit: a tendon anchored in silicone (not in a bone) pulls on a point, and in
2D the displacement under a point force is log-singular: the answer near the
anchor keeps changing with refinement (finger_soft.toml, P2: the tip moves
0.45 mm from h = 2 to 1.5 and 0.35 mm more to h = 1), so no size is sure to
meet a tolerance there. Anchor tendons in
bones, or read the estimate as a guide only.
"""
from __future__ import annotations

from dataclasses import dataclass

U_REF = 46.3                                    # mm, tip motion of the calibration run
ERROR = {1: (0.50, 0.99), 2: (0.086, 1.47)}     # C_p [mm / mm^r], r_p
COST = {1: (0.685, 1.78), 2: (3.16, 2.14)}      # T_p [s mm^q], q_p
SAFETY = 2.0
H_MIN, H_MAX = 0.35, 4.0
PRESOLVE = {"degree": 2, "size": 4.0}


@dataclass(frozen=True)
class Choice:
    degree: int
    size: float
    estimate: float       # estimated marker error at (degree, size), mm
    cost: float           # predicted relative cost
    met: bool             # whether the estimate meets the tolerance within [H_MIN, H_MAX]


def error_estimate(degree: int, size: float, motion: float) -> float:
    C, r = ERROR[degree]
    return C * (motion / U_REF) * size ** r


def size_for(degree: int, tol: float, motion: float) -> float:
    """Coarsest h in [H_MIN, H_MAX] with SAFETY * e_p(h) <= tol (H_MIN if none)."""
    C, r = ERROR[degree]
    scale = max(C * motion / U_REF, 1e-300)
    h = (tol / (SAFETY * scale)) ** (1.0 / r)
    return float(min(max(h, H_MIN), H_MAX))


def choose(tol: float, motion: float, nu_max: float) -> Choice:
    """The cheapest (degree, size) whose estimated marker error stays below tol."""
    choices = []
    for p in ((2,) if nu_max > 0.49 else (1, 2)):
        h = size_for(p, tol, motion)
        T, q = COST[p]
        e = error_estimate(p, h, motion)
        choices.append(Choice(p, round(h, 3), e, T * h ** -q, SAFETY * e <= tol * (1 + 1e-9)))
    met = [c for c in choices if c.met] or choices
    return min(met, key=lambda c: (c.cost, -c.degree) if c.met else (c.estimate, c.cost))

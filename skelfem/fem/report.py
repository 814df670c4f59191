"""What a static solve reports: SolveReport (result.json's status, iterations, histories) and SolveError."""
from __future__ import annotations

from dataclasses import dataclass, field


BUDGET_SPENT = "frame_budget"   # status of a warm re-solve stopped at its deadline (LoadStepper.deadline)


class SolveError(RuntimeError):
    """Raised by callers that need an equilibrium and did not get one."""


@dataclass
class SolveReport:
    converged: bool
    status: str
    newton_iterations: int = 0
    load_steps: int = 0
    residual_history: list = field(default_factory=list)   # one list of |R| per load step
    attempts: list = field(default_factory=list)           # every Newton run: factor, iterations, status
    energy: float = float("nan")
    min_jacobian: float = float("nan")
    time: float = 0.0
    linear_solver: str = "direct"                           # "direct" (MUMPS) or "iterative" (CG + GAMG)
    linear_iterations: list = field(default_factory=list)  # iterative: Krylov iterations per Newton step,
    #                                                       one list per load step
    linear_fallbacks: int = 0                               # iterative: Newton steps solved by MUMPS instead
    linear_loose_steps: int = 0                             # ... taken from a stalled Krylov solve

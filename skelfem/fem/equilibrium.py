"""The last converged state of a model: the state u and the value of every live parameter.

A re-solve that finds both unchanged has nothing to solve. With friction it
must not start a new step: the step would begin with new anchors and lags and
could settle at another of friction's many equilibria (a gripper's second
solve took 109 Newton iterations and turned the pair's friction around).
"""
from __future__ import annotations

import numpy as np
from mpi4py import MPI


class Equilibrium:
    """Remembers (u, parameters) of a converged solve; ``holds`` tells whether the model is still there."""

    def __init__(self):
        self._state = None

    @staticmethod
    def _parameters(model) -> dict:
        return {k: np.array(v, dtype=float) for k, v in model.parameters().items()}

    def mark(self, model) -> None:
        self._state = (model.u.x.array.copy(), self._parameters(model))

    def forget(self) -> None:
        self._state = None

    def holds(self, model) -> bool:
        """The model is at the marked state with the same parameters (the same answer on every rank)."""
        if self._state is None:
            return False
        u, params = self._state
        now = self._parameters(model)
        same = np.array_equal(u, model.u.x.array) and now.keys() == params.keys() \
            and all(np.array_equal(now[k], params[k]) for k in now)
        return bool(model.comm.allreduce(same, op=MPI.LAND))

"""Following an edit that keeps the mesh, and packed form coefficients shared while they are unchanged.
"""
from __future__ import annotations

import numpy as np
from dolfinx import cpp as _cpp



MODEL_KEYS = ("format", "dim", "thickness", "mesh")   # design keys no term follows: a new model


class CannotFollow(Exception):
    """An ingredient with a UFL energy would have to be built anew (Model.refresh)."""


class PackedCoefficients:
    """Packed coefficients of the compiled forms, shared while the coefficients are unchanged.

    Pi, grad Pi and hess Pi have the same coefficients (u and the material
    fields), and a Newton iteration evaluates them at the same state (the
    accepted trial's energy, then the residual and the Jacobian there), so
    one packing serves all three; the Jacobian's assembly then forgets it
    (``clear``), since the next evaluation is at a new state and the pack
    (0.2 KB per DOF of a 3D P1 mesh) would sit beside the multigrid's
    set-up. A pack is reused only while every
    coefficient array equals, entry by entry, the one it was packed from;
    forms whose coefficients or integrals differ get their own pack.
    """

    def __init__(self):
        self.packs: dict = {}      # form signature -> (copies of the coefficient arrays, packed coefficients)

    @staticmethod
    def _signature(form) -> tuple:
        integrals = tuple((t, tuple(form.integral_ids(t))) for t in form.integral_types)
        return tuple(id(c) for c in form.coefficients), integrals

    def __call__(self, form) -> dict:
        key = self._signature(form)
        arrays = [c.x.array for c in form.coefficients]
        held = self.packs.get(key)
        if held is None or not all(np.array_equal(a, b) for a, b in zip(arrays, held[0])):
            held = self.packs.pop(key, None)     # the stale pack freed before the new one is made:
            del held                             # never two packs of a form alive at once
            held = self.packs[key] = ([a.copy() for a in arrays], _cpp.fem.pack_coefficients(form))
        return held[1]

    def clear(self) -> None:
        """Forget every pack (after the Jacobian: the next evaluation is at a new state, and meanwhile
        the memory serves the preconditioner's set-up)."""
        self.packs.clear()

"""fem/follow (from model.py)

The model: Pi(u; a) = sum of the registered terms, and its derivatives.

Every physical ingredient is a term (:mod:`skelfem.terms`); the model builds
them from the design, sums their UFL energies into one form compiled once
(with its residual and Jacobian forms), and adds the hand-written ones on
their few DOFs. It names no ingredient. The solver sees ``energy``,
``residual``, ``jacobian`` (the sparse Newton matrix K), ``low_rank`` (the
rank-one parts c g g^T kept out of K), ``admissible``, ``max_step`` and
``step_correction``; output reads ``readouts``; control reads and writes
``parameters``.

Dirichlet DOFs (fixed pins) have identity rows and columns in K and carry no
term entries, and their entries of every low-rank vector are zero.

Rigid bodies (``Term.rigid_body``: rigid bones) are solved for their rigid
DOFs q: their nodes' rows of K become identity rows and columns too, after
K T (T = du_b/dq) has given the coupling E and the reduced block
C = T^T K T + sum_i R_i . d2u_i/dq2 of the linear solver's border
(:class:`skelfem.linear.Border`, ``border``). In serial the border lives in
K itself: each body's q takes the rows and columns of the first DOFs of its
first nodes (its *hosts*), which hold E and C, so one factorisation covers
it; under MPI the linear solver adds it from K^{-1} E. The residual on those
rows is the projection of grad Pi onto the rigid modes, and ``apply_bcs``
puts every rigid body exactly on its closest rigid motion.

``refresh`` makes the model follow an edit that keeps the mesh (moved nodes,
cables, markers, pins...) without compiling anything again: terms follow in
place or are built anew, and the Newton matrix is kept while its pattern holds.
"""
from __future__ import annotations

import numpy as np
from dolfinx import cpp as _cpp



MODEL_KEYS = ("format", "dim", "thickness", "mesh")   # design keys no term follows: a new model


class CannotFollow(Exception):
    """An ingredient with a UFL energy would have to be built anew (Model.refresh)."""


def raw_value(raw: dict, key: str):
    """The value of a dotted design key (named entries by name) in a design's raw dict."""
    node = raw
    for part in key.split("."):
        if isinstance(node, list):
            node = next(e for e in node if isinstance(e, dict) and e.get("name") == part)
        else:
            node = node[part]
    return node


class PackedCoefficients:
    """Packed coefficients of the compiled forms, shared while the coefficients are unchanged.

    Pi, grad Pi and hess Pi have the same coefficients (u and the material
    fields), and a Newton iteration evaluates them at the same state (the
    accepted trial's energy, then the residual and the Jacobian there), so
    one packing serves all three. A pack is reused only while every
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
            held = self.packs[key] = ([a.copy() for a in arrays], _cpp.fem.pack_coefficients(form))
        return held[1]

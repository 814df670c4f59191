"""What a Newton step's linear solve takes besides K: the rank-one parts c_i g_i g_i^T of the cables
(as c and a sparse G, one column per part), the border of rigid bones, and the sparse products of the
deflation blocks (skelfem.fem.linear)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass
class Border:
    """Border unknowns z of a linear solve (see the module docstring); arrays on owned rows."""
    T: np.ndarray        # (n, m): the slaved rows' values per unit z (zero elsewhere)
    rows: np.ndarray     # (n,) bool: the slaved rows (identity rows and columns of K)
    E: np.ndarray        # (n, m): K_full T on the other rows (zero on slaved and Dirichlet rows)
    C: np.ndarray        # (m, m): the reduced block T^T K T (+ second-order terms), same on every rank
    hosts: np.ndarray | None = None   # (m,): slaved rows of K that hold z (E and C already in K), serial

    def embed(self, v: np.ndarray) -> np.ndarray:
        """(v_f, T^T v on the hosts) of a full vector v (or of the columns of a block)."""
        out = v * (~self.rows if v.ndim == 1 else ~self.rows[:, None])
        out[self.hosts] = self.T.T @ v
        return out

    def expand(self, y: np.ndarray) -> np.ndarray:
        """x = y_f + T z of a solution y of the embedded system, z = y on the hosts."""
        return y * ~self.rows + self.T @ y[self.hosts]


def columns(parts, n: int) -> tuple[np.ndarray, sp.csc_matrix]:
    """(c, G sparse) of rank-one parts given as (c, G) or [(c_i, g_i)] with g_i PETSc vectors."""
    if isinstance(parts, tuple):
        return np.asarray(parts[0], dtype=float), sp.csc_matrix(parts[1])
    G = sp.hstack([sp.csc_matrix(g.array_r[:, None]) for _, g in parts], format="csc") if parts else \
        sp.csc_matrix((n, 0))
    return np.array([c for c, _ in parts], dtype=float), G


def dense(G) -> np.ndarray:
    """G as a dense array (a fallback factorisation's right-hand sides)."""
    return G.toarray() if sp.issparse(G) else G


def sparse_product(K, W: sp.spmatrix) -> sp.csr_matrix:
    """K W for a PETSc matrix K and a sparse W (owned rows), one column at a time: sparse again (the
    rows W touches and their neighbours), so that no dense n x p block is ever held."""
    x, y = K.createVecRight(), K.createVecLeft()
    cols = []
    W = W.tocsc()
    for j in range(W.shape[1]):
        x.array_w[:] = W[:, [j]].toarray()[:, 0]
        K.mult(x, y)
        cols.append(sp.csc_matrix(y.array_r[:, None]))
    x.destroy()
    y.destroy()
    return sp.hstack(cols).tocsr()


def sparse_dots(A, B, comm) -> np.ndarray:
    """A^T B summed over ranks, A sparse, B sparse or dense: a dense array."""
    out = A.T @ B
    out = out.toarray() if hasattr(out, "toarray") else np.asarray(out)
    return out if comm.size == 1 else comm.allreduce(out)

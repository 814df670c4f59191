"""The Newton matrix: one fixed pattern (finite elements, term blocks, rigid borders) and its assembly.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from dolfinx import cpp as _cpp
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from ..terms.base import CooBlock
from .lowrank import Border




class PatternOutgrown(Exception):
    """A term's Hessian needs entries outside the Newton matrix's pattern (contact pairs that formed):
    make a new matrix (Model.create_matrix) and assemble again."""


def assemble_form(A: PETSc.Mat, form, bcs, coefficients=None) -> None:
    coefficients = _cpp.fem.pack_coefficients(form) if coefficients is None else coefficients
    _cpp.fem.petsc.assemble_matrix(A, form, _cpp.fem.pack_constants(form), coefficients, bcs)


def block_keys(blocks, n: int) -> np.ndarray:
    """Sorted unique node pairs row * n + column of pattern blocks [(row nodes, column nodes)]; blocks
    of one shape are stacked, so the work is a few array operations per shape, not per block."""
    by_shape: dict = {}
    for rn, cn in blocks:
        by_shape.setdefault((len(rn), len(cn)), ([], []))
        by_shape[len(rn), len(cn)][0].append(rn)
        by_shape[len(rn), len(cn)][1].append(cn)
    keys = [(np.asarray(R, np.int64)[:, :, None] * n + np.asarray(C, np.int64)[:, None, :]).ravel()
            for R, C in by_shape.values()]
    return np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)


class MatrixAssembly:
    """The Newton matrix of a Model (a mixin: the model holds V, the terms, the rigid bodies).

    Serial, with rigid bodies: the terms' entries on a rigid body's DOFs
    never enter the sparse matrix (its rows and columns become the identity
    and the border anyway); they are kept aside (``_aside``) and added to
    K T when the border is built. A contact block between the body and a
    rigid object's boundary would otherwise couple every node of the two
    in the pattern, and the factorisation would fill in over them."""

    # What the host (the Model) holds and this mixin reads, named for the type checker.
    comm: Any
    V: fem.FunctionSpace
    u: fem.Function
    terms: list
    rigid: Any
    bcs: list
    bs: int
    n_local: int
    n_owned: int
    global_dofs: np.ndarray
    fixed: np.ndarray
    slaved: Any
    jacobian_form: Any
    gradient: Any
    sync: Any
    embed_border: Any
    _packs: Any
    _block_cache: Any
    _fixed_cache: Any
    _csr_cache: Any
    _extra_rows: Any
    _slaved_rows: Any
    _last_gradient: Any

    def _term_blocks(self, term):
        """The term's pattern blocks as (global rows this rank sets, global columns)."""
        bs = self.bs
        for rn, cn in term.pattern():
            rows = (np.asarray(rn, np.int64)[:, None] * bs + np.arange(bs)).ravel()
            cols = (np.asarray(cn, np.int64)[:, None] * bs + np.arange(bs)).ravel()
            if term.gather is None:
                rows, cols = self.global_dofs[rows], self.global_dofs[cols]
            lo = self.V.dofmap.index_map.local_range[0] * bs
            rows = rows[(rows >= lo) & (rows < lo + self.n_owned)]
            yield rows.astype(PETSc.IntType), cols.astype(PETSc.IntType)

    def _form_cells(self) -> np.ndarray:
        """The cells the Hessian's form integrates over (rigid bodies' cells are not among them)."""
        form, kind = self.jacobian_form, fem.IntegralType.cell
        return np.unique(np.concatenate([form.domains(kind, i) for i in form.integral_ids(kind)]))

    def _cell_pattern(self):
        """The UFL Hessian's pattern from the cells its form integrates over only (DOLFINx's own
        pattern takes every cell): the cells of rigid bodies add no entries."""
        imap = self.V.dofmap.index_map
        pattern = _cpp.la.SparsityPattern(self.comm, [imap, imap], [self.bs, self.bs])
        dofmap = self.V.dofmap.list
        for c in self._form_cells():
            nodes = dofmap.links(c)
            pattern.insert(nodes, nodes)
        return pattern

    def _border_pattern(self, blocks) -> tuple[list, list | None]:
        """Serial rigid bodies: the pattern blocks that put the border into K, and the host map.

        Body j's q_j takes the rows and columns of the first m_j DOFs of its
        first ceil(m_j / bs) nodes (its hosts; m_j = 3 in 2D, 6 in 3D). Its
        coupling E_j = (K T)_j is non-zero on the rows of K that reach the
        body: the nodes of every assembled cell or term block (``blocks``:
        (row nodes, column nodes)) that touches one of its nodes. Returns
        ([(rows, cols)] node blocks: hosts x coupled, coupled x hosts, hosts x
        hosts), [(host DOFs, coupled DOFs)] per body); ([], None) under MPI or
        without rigid bodies.
        """
        if self.comm.size != 1 or not self.rigid or not self.embed_border:
            return [], None
        bs, n = self.bs, self.n_local // self.bs
        npc = self.V.dofmap.dof_layout.num_dofs
        cell_nodes = self.V.dofmap.list.array.reshape(-1, npc)[self._form_cells()]
        rows, cols = np.divmod(block_keys(blocks, n), n)          # every node pair of the blocks
        out, hosts = [], []
        for body in self.rigid:
            nodes = np.unique(body.dofs[:, 0] // bs)
            inside = np.zeros(n, dtype=bool)
            inside[nodes] = True
            near = np.unique(np.concatenate([cell_nodes[inside[cell_nodes].any(axis=1)].ravel(),
                                             rows[inside[cols]], cols[inside[rows]]]).astype(np.int64))
            near = near[~inside[near]]
            host_nodes = body.dofs[:-(-body.m // bs), 0] // bs
            out += [(host_nodes, near), (near, host_nodes)]
            hosts.append((body.dofs[:-(-body.m // bs)].ravel()[:body.m],
                          (near[:, None] * bs + np.arange(bs)).ravel()))
        every = np.concatenate([h for h, _ in hosts]) // bs
        out.append((every, every))
        return out, hosts

    def _follower_nodes(self) -> np.ndarray | None:
        """Serial: which local nodes follow a rigid body (None under MPI or without rigid bodies)."""
        if self.comm.size != 1 or not self.rigid:
            return None
        out = np.zeros(self.n_local // self.bs, dtype=bool)
        for body in self.rigid:
            out[np.asarray(body.dofs)[:, 0] // self.bs] = True
        return out

    def create_matrix(self) -> PETSc.Mat:
        """The sparse Newton matrix K: the UFL Hessian's pattern plus every term's (sparse) blocks.

        Every entry the Jacobian will ever touch is created here, as a zero,
        before the first final assembly (PETSc drops unused preallocated
        slots then); afterwards the pattern never changes (new entries
        raise), so MUMPS reuses its analysis across Newton iterations.
        """
        pattern = self._cell_pattern() if self.rigid else fem.create_sparsity_pattern(self.jacobian_form)
        if self.comm.size == 1:        # serial: the term blocks (and the rigid border) go into DOLFINx's pattern
            blocks = [block for term in self.terms for block in term.pattern()] + self._extra_rows()
            border_blocks, self._hosts = self._border_pattern(blocks)
            follower = self._follower_nodes()
            for rn, cn in blocks:      # a rigid body's nodes: kept aside (see the class)
                rn, cn = np.asarray(rn, np.int32), np.asarray(cn, np.int32)
                if follower is not None:
                    rn, cn = rn[~follower[rn]], cn[~follower[cn]]
                if len(rn) and len(cn):
                    pattern.insert(rn, cn)
            if follower is not None:   # their diagonal: the identity rows
                pattern.insert_diagonal(np.flatnonzero(follower).astype(np.int32))
            for rn, cn in border_blocks:
                pattern.insert(np.asarray(rn, np.int32), np.asarray(cn, np.int32))
        pattern.assemble()
        A = _cpp.la.petsc.create_matrix(self.comm, pattern)
        if self.comm.size == 1:
            graph = pattern.graph
            n_owned = pattern.index_map(0).size_local
            offsets = graph.offsets[:n_owned + 1]
            rows = np.repeat(np.arange(n_owned, dtype=np.int64), np.diff(offsets))
            self._pattern_keys = np.sort(rows * (self.n_local // self.bs) + graph.array[:offsets[-1]])
            zeros = np.zeros(offsets[-1] * self.bs * self.bs, dtype=PETSc.ScalarType)
            A.setValuesBlockedLocalCSR(offsets.astype(PETSc.IntType),
                                       graph.array[:offsets[-1]].astype(PETSc.IntType),
                                       zeros, addv=PETSc.InsertMode.INSERT_VALUES)
        else:                          # MPI: element entries by one assembly, term blocks by their owners
            self._preallocate(A, pattern)
            assemble_form(A, self.jacobian_form, self.bcs)
            A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
            for term in self.terms:
                for rows, cols in self._term_blocks(term):
                    if len(rows):
                        A.setValues(rows, cols, np.zeros((len(rows), len(cols))),
                                    addv=PETSc.InsertMode.ADD_VALUES)
            A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()
        A.zeroEntries()
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)     # identity rows of rigid bodies
        return A

    def _preallocate(self, A: PETSc.Mat, pattern) -> None:
        """MPI: room in each owned row for the element pattern and the terms' blocks (their columns may
        lie on any rank, outside the pattern's ghosts, so they are not in it), before any entry is set:
        each entry beyond the preallocation would copy the row storage (a cable's 397 blocks on arm3d
        took 14 s). Counts are upper bounds (a repeated column is counted again)."""
        bs, n = self.bs, self.n_owned
        lo = A.getOwnershipRange()[0]
        graph = pattern.graph
        rows = pattern.index_map(0).size_local
        offsets = graph.offsets[:rows + 1]
        local_cols = pattern.column_index_map().size_local
        diag_cols = np.add.reduceat((graph.array[:offsets[-1]] < local_cols).astype(np.int64),
                                    offsets[:-1]) if offsets[-1] else np.zeros(rows, np.int64)
        diag_cols[np.diff(offsets) == 0] = 0                  # reduceat gives an empty row its next value
        d = np.repeat(diag_cols * bs, bs)
        o = np.repeat((np.diff(offsets) - diag_cols) * bs, bs)
        for term in self.terms:
            for r, c in self._term_blocks(term):
                if len(r):
                    inside = int(np.count_nonzero((c >= lo) & (c < lo + n)))
                    np.add.at(d, r - lo, inside)
                    np.add.at(o, r - lo, len(c) - inside)
        N = A.getSize()[0]
        A.setPreallocationNNZ((np.minimum(d, n).astype(PETSc.IntType),
                               np.minimum(o, N - n).astype(PETSc.IntType)))

    def free_of(self, term, dofs) -> np.ndarray:
        """Which of a term's DOFs are not Dirichlet DOFs."""
        if term.gather is None:
            return ~self.fixed[dofs]
        key = id(term)
        if key not in self._fixed_cache:
            self._fixed_cache[key] = term.gather(self.fixed.astype(float)) > 0.5
        return ~self._fixed_cache[key]

    def _owned_rows(self, term, dofs) -> tuple[np.ndarray, np.ndarray]:
        """(positions in dofs of the rows this rank sets, their global numbers)."""
        if term.gather is None:
            pos = np.flatnonzero(np.asarray(dofs) < self.n_owned)
            return pos, self.global_dofs[np.asarray(dofs)[pos]]
        return term.gather.pos, np.asarray(dofs, np.int64)[term.gather.pos]

    def _block_map(self, term, dofs, row, col) -> tuple:
        """Which entries of a term's COO block this rank adds (owned, free rows and columns), and where."""
        free = self.free_of(term, dofs)
        pos, grow = self._owned_rows(term, dofs)
        keep = np.zeros(len(dofs), dtype=bool)
        keep[pos] = True
        ok = keep[row] & free[row] & free[col]
        aside = np.zeros(0, np.int64)
        if self.comm.size == 1 and self.rigid:               # entries on rigid bodies' DOFs: kept aside
            slaved = self.slaved[np.asarray(dofs)]
            on_rigid = slaved[row] | slaved[col]
            aside = np.flatnonzero(ok & on_rigid)
            ok &= ~on_rigid
        sel = np.flatnonzero(ok)
        gcol = self.global_dofs[np.asarray(dofs)] if term.gather is None else np.asarray(dofs, np.int64)
        rowmap = np.full(len(dofs), -1, np.int64)
        rowmap[pos] = grow
        local = np.asarray(dofs)
        return sel, rowmap[row[sel]], gcol[col[sel]], aside, local[row[aside]], local[col[aside]]

    def _term_blocks_at(self, u: np.ndarray) -> tuple[list, list]:
        """Every term's sparse Hessian blocks at u: ([(dofs, row, col, sel, rows, cols)], [values]).

        A block whose dofs, row and column arrays are the same objects as last
        time (a cable's curvature) reuses its map into the matrix.
        """
        blocks, values = [], []
        aside: tuple[list, list, list] = ([], [], [])
        for term in self.terms:
            for i, (dofs, H) in enumerate(term.hessian(u)):
                H = H if isinstance(H, CooBlock) or sp.isspmatrix_coo(H) else sp.coo_matrix(H)
                if H.nnz == 0:
                    continue
                c = self._block_cache.get((id(term), i))
                if c is None or c[0] is not dofs or c[1] is not H.row or c[2] is not H.col:
                    c = (dofs, H.row, H.col, *self._block_map(term, dofs, H.row, H.col))
                    self._block_cache[(id(term), i)] = c
                blocks.append(c)
                values.append(H.data[c[3]])
                if len(c[6]):
                    for out, a in zip(aside, (H.data[c[6]], c[7], c[8])):
                        out.append(a)
        n = self.n_owned
        self._aside = None if not aside[0] else sp.coo_matrix(
            (np.concatenate(aside[0]), (np.concatenate(aside[1]), np.concatenate(aside[2]))), shape=(n, n)).tocsr()
        return blocks, values

    def _add_term_blocks(self, A: PETSc.Mat, u: np.ndarray) -> None:
        """A += the terms' sparse Hessian blocks, duplicates summed; the CSR layout is kept while it holds."""
        blocks, values = self._term_blocks_at(u)
        grown = [t for t in self.terms if getattr(t, "outgrown", False)]
        if grown:                  # their pattern grew to hold these blocks: the matrix must be made anew
            for t in grown:
                t.outgrown = False
            raise PatternOutgrown(", ".join(f"{t.section}.{t.name}" for t in grown))
        if not blocks:
            return
        cache = self._csr_cache
        if cache is None or len(cache[0]) != len(blocks) or any(a is not c[1] for a, c in zip(cache[0], blocks)):
            rows = np.concatenate([c[4] for c in blocks])
            cols = np.concatenate([c[5] for c in blocks])
            order = np.lexsort((cols, rows))
            r, k = rows[order], cols[order]
            new = np.r_[True, (r[1:] != r[:-1]) | (k[1:] != k[:-1])] if len(r) else np.zeros(0, bool)   # no rows here
            slot = np.empty(len(order), np.int64)
            slot[order] = np.cumsum(new) - 1
            urows, counts = np.unique(r[new], return_counts=True)
            indptr = np.r_[0, np.cumsum(counts)].astype(PETSc.IntType)
            cache = ([c[1] for c in blocks], slot, int(new.sum()), urows.astype(PETSc.IntType),
                     indptr, k[new].astype(PETSc.IntType))
            self._csr_cache = cache
        _, slot, n, urows, indptr, indices = cache
        data = np.bincount(slot, weights=np.concatenate(values), minlength=n)
        A.setValuesIJV(indptr, indices, data, addv=PETSc.InsertMode.ADD_VALUES, rowmap=urows)

    def assemble_jacobian(self, x: PETSc.Vec, A: PETSc.Mat) -> PETSc.Mat:
        """K at x into A, or into a new matrix when a term's pattern grew (PatternOutgrown); returns the
        matrix that holds K (the caller destroys A when it is not that one)."""
        try:
            self.jacobian(x, A)
            return A
        except PatternOutgrown:
            B = self.create_matrix()
            self.jacobian(x, B)
            return B

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """K = hess Pi without the rank-one parts, Dirichlet rows and columns replaced by the identity."""
        u = self.sync(x)
        A.zeroEntries()
        assemble_form(A, self.jacobian_form, self.bcs, self._packs(self.jacobian_form))   # adds; so do the terms
        self._packs.clear()
        self._add_term_blocks(A, u)
        A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
        A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
        _cpp.fem.petsc.insert_diagonal(A, self.V._cpp_object, self.bcs, 1.0)
        A.assemble()
        if self.rigid:
            self._reduce_rigid(x, A)

    def _reduce_rigid(self, x: PETSc.Vec, A: PETSc.Mat) -> None:
        """The border of the rigid bodies from the assembled K (E = K T off their rows, C = T^T K T +
        sum R . d2u/dq2), then their rows and columns of K replaced by the identity."""
        u = self.u.x.array.copy()
        last = self._last_gradient
        if last is not None and np.array_equal(last[0], x.array_r):
            grad = last[1]                  # SNES evaluated the residual at x just before
        else:
            b = x.duplicate()
            self.gradient(x, b)
            fem_petsc.set_bc(b, self.bcs, x, -1.0)
            grad = b.array_r.copy()
            b.destroy()
        blocks = [(body, body.modes(u)) for body in self.rigid]
        m = sum(body.m for body in self.rigid)
        T = np.zeros((self.n_owned, m))
        j = 0
        for body, Tb in blocks:
            T[body.dofs.ravel(), j:j + body.m] = Tb.reshape(-1, body.m)
            j += body.m
        Ts = sp.csc_matrix(T)
        if self.comm.size == 1:     # K T as sparse x sparse (T holds each body's few DOFs per column): PETSc's
            ai, aj, av = A.getValuesCSR()   # sparse x dense product took 9.7 s for 400 boxes (1,200 columns)
            K = sp.csr_matrix((av, aj, ai), shape=(self.n_owned, self.n_owned))
            KT = (K @ Ts).toarray()
        else:
            n_global = self.V.dofmap.index_map.size_global * self.bs
            B = PETSc.Mat().createDense([(self.n_owned, n_global), (None, m)], array=T, comm=self.comm)
            KB = A.matMult(B)                                # K T, one sparse-dense product
            KT = KB.getDenseArray().copy()
            KB.destroy()            # not left to the garbage collector: it leaked K T and T per call
            B.destroy()
        aside = getattr(self, "_aside", None)
        if aside is not None:                                # the terms' entries kept out of A (serial)
            KT += aside @ T
        C = Ts.T @ KT               # T^T K T: T's few entries per column, not a dense (m x n) x (n x m) product
        C = C if self.comm.size == 1 else self.comm.allreduce(C)
        j = 0
        for body, _ in blocks:
            C[j:j + body.m, j:j + body.m] += body.second_derivative(u, grad)
            j += body.m
        KT[self.slaved] = 0.0
        C = 0.5 * (C + C.T)
        A.zeroRowsColumns(self._slaved_rows, diag=1.0)
        hosts = None if self._hosts is None else self._embed_border(A, KT, C)
        self.border = Border(T, self.slaved, KT, C, hosts)
        self.sync(x)

    def _embed_border(self, A: PETSc.Mat, KT: np.ndarray, C: np.ndarray) -> np.ndarray:
        """Write E = K T and C into the hosts' rows and columns of A (serial); the host DOFs in q's order."""
        g, j, insert = self.global_dofs, 0, PETSc.InsertMode.INSERT_VALUES
        assert self._hosts is not None          # called only when the border has hosts
        for host, near in self._hosts:
            E = KT[near, j:j + len(host)]
            A.setValues(g[near], g[host], E, addv=insert)
            A.setValues(g[host], g[near], E.T.copy(), addv=insert)
            j += len(host)
        hosts = np.concatenate([h for h, _ in self._hosts])
        A.setValues(g[hosts], g[hosts], C, addv=insert)
        A.assemble()
        return hosts


"""The state as numbers (vertex displacements, regions, cables, markers) gathered on rank 0, and
solution.xdmf / trajectory.xdmf.
"""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from mpi4py import MPI

from .files import atomic_write


def _floats(a) -> list:
    return [float(v) for v in np.asarray(a, dtype=float).ravel()]


# -- the state as numbers ------------------------------------------------------------------------
def vertex_displacements(model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest node coordinates, displacement at the nodes, triangles/tets) of the P1 geometry."""
    mesh, V = model.mesh, model.V
    tdim, gdim = mesh.topology.dim, mesh.geometry.dim
    x = mesh.geometry.x[:, :gdim]
    geo = mesh.geometry.dofmap.array.reshape(-1, tdim + 1)
    dofs = V.dofmap.list.array.reshape(len(geo), -1)[:, :tdim + 1]   # vertex DOFs come first
    node_dof = np.empty(len(x), dtype=np.int64)
    node_dof[geo.ravel()] = dofs.ravel()
    u = model.u.x.array.reshape(-1, model.bs)[node_dof]
    return x, u, geo


STICKING, SLIPPING = 1.0, 2.0     # contact_state: 0 no friction anchor (free, or a frictionless contact)


def contact_forces(model) -> tuple[np.ndarray, np.ndarray] | None:
    """(contact_force, contact_traction) of contact_fields, or None without contact."""
    fields = contact_fields(model)
    return None if fields is None else (fields["contact_force"], fields["contact_traction"])


def contact_fields(model) -> dict | None:
    """Where pieces (bodies, objects) can touch, or a body itself (self-contact): at every node of the
    (local) P1 geometry, {name: (n, dim) or (n,)}: ``contact_force`` (N), the barrier's and friction's force
    the other pieces (and other parts of its own body) exert on it, split into ``contact_normal_force``
    (the barriers') and ``contact_friction_force``; ``contact_traction``
    (MPa), that force over the node's share of the boundary (2D: half its edges' lengths times the
    thickness; 3D: a third of its triangles' areas); ``contact_state``, STICKING (1) or SLIPPING (2) for a
    node anchored by friction on another piece (as the pairs' ``sticking`` counts it), 0 otherwise. A P2
    edge midpoint's forces and share go half to each end of its edge; None without such contact.
    Collective: under MPI every rank has the whole boundary's forces (global node numbers) and keeps its
    own geometry nodes'."""
    barriers = [t for section in ("contacts", "contact") for t in model.terms_in(section) if hasattr(t, "nodal_forces")]
    if not barriers:
        return None
    pieces = barriers[0]                 # every barrier's rows are the same boundary nodes (boundary_facets)
    _, normal, friction = pieces.nodal_forces(model)
    for other in barriers[1:]:
        normal = normal + other.nodal_forces(model)[1]
    state = np.zeros(len(normal))
    rubbing = next((t for t in model.terms_in("contacts") if hasattr(t, "vertex_states")), None)
    if rubbing is not None:
        anchored, slipping, N = rubbing.vertex_states(model.u.x.array)
        on = anchored & (N > 0)
        state[on] = np.where(slipping[on], SLIPPING, STICKING)
    X, edges, facets = pieces.X, pieces.edges, pieces.facets
    side = X[facets[:, 1:]] - X[facets[:, :1]]
    dim = X.shape[1]
    measure = (np.linalg.norm(side[:, 0], axis=1) if dim == 2
               else 0.5 * np.linalg.norm(np.cross(side[:, 0], side[:, 1]), axis=1))
    w = np.zeros(len(X))
    np.add.at(w, facets.ravel(), np.repeat(measure / dim, dim))
    mesh, V = model.mesh, model.V
    tdim = mesh.topology.dim
    geo = mesh.geometry.dofmap.array.reshape(-1, tdim + 1)
    dofs = V.dofmap.list.array.reshape(len(geo), -1)[:, :tdim + 1]
    imap = V.dofmap.index_map
    geom_of_node = np.full(imap.size_local + imap.num_ghosts, -1, np.int64)
    geom_of_node[dofs.ravel()] = geo.ravel()
    if model.comm.size == 1:
        where = geom_of_node[pieces.nodes]                  # -1: a P2 midpoint
        mid = where < 0
    else:                                                   # -1 also: a node this rank does not have
        glob = imap.local_to_global(np.arange(len(geom_of_node), dtype=np.int32)).astype(np.int64)
        at = np.minimum(np.searchsorted(pieces.nodes, glob), len(pieces.nodes) - 1)
        hit = pieces.nodes[at] == glob
        where = np.full(len(pieces.nodes), -1, np.int64)
        where[at[hit]] = geom_of_node[hit]
        vertex = np.zeros(len(pieces.nodes), np.int8)
        vertex[at[hit]] = geom_of_node[hit] >= 0
        model.comm.Allreduce(MPI.IN_PLACE, vertex, op=MPI.MAX)
        mid = vertex == 0
    if mid.any():                                           # its two edges lead to the two ends
        a, b = edges[:, 0], edges[:, 1]
        for s, t in ((a, b), (b, a)):
            m = mid[s] & ~mid[t]
            for values in (normal, friction, w):
                np.add.at(values, t[m], 0.5 * values[s[m]])
    keep = ~mid & (where >= 0)
    n = len(mesh.geometry.x)
    out = {}
    for name, values in (("contact_normal_force", normal), ("contact_friction_force", friction)):
        out[name] = np.zeros((n, dim))
        np.add.at(out[name], where[keep], values[keep])
    out["contact_force"] = out["contact_normal_force"] + out["contact_friction_force"]
    share = np.zeros(n)
    np.add.at(share, where[keep], w[keep])
    out["contact_traction"] = np.divide(out["contact_force"], share[:, None] * pieces.t,
                                        out=np.zeros((n, dim)), where=share[:, None] > 0)
    out["contact_state"] = np.zeros(n)
    np.maximum.at(out["contact_state"], where[keep], state[keep])
    return out


def cell_regions(model) -> np.ndarray:
    """Tag value of every local cell (body = 1, bones after)."""
    n = model.mesh.topology.index_map(model.mesh.topology.dim).size_local
    tags = np.zeros(n, dtype=np.int32)
    ct = model.tm.cell_tags
    owned = ct.indices < n
    tags[ct.indices[owned]] = ct.values[owned]
    return tags


def cable_states(model) -> list[dict]:
    u = model.u.x.array
    out = []
    for term in model.terms_in("cables"):
        c, L = term.cable, term.rest_length
        out.append({"name": c.name, "kind": c.kind, "rest": c.X, "deformed": c.positions(u),
                    "length": c.length(u), "rest_length": L, "tension": c.tension(u, L),
                    "tensions": c.tensions(u, L)})
    return out


def marker_positions(model) -> dict:
    """{name: current position} of the design's markers (collective under MPI)."""
    terms = model.terms_in("markers")
    if not terms:
        return {}
    return dict(zip(terms[0].names, terms[0].positions(model.u.x.array)))


def object_states(model) -> list[dict]:
    """Per free object: its name and outline moved by its rigid motion, and the contact forces on its
    boundary nodes from the other pieces (positions, barrier and friction forces, N; collective). Then,
    without an outline, every body but the first that something touches, with the forces on it."""
    objects = model.terms_in("objects")
    pieces: Any = next((t for t in model.terms_in("contacts") if hasattr(t, "nodal_forces")), None)
    if not objects and pieces is None:
        return []
    nodal: Any = pieces.nodal_forces(model) if pieces is not None else (None, None, None)
    y, normal, friction = nodal

    def forces_on(k: int) -> dict:
        touched = (pieces.label == k) & (np.linalg.norm(normal, axis=1) + np.linalg.norm(friction, axis=1) > 0)
        return {"points": y[touched], "normal": normal[touched], "friction": friction[touched]}
    out = []
    bodies = len(model.design.bodies)
    for k, obj in enumerate(objects, start=bodies):
        entry = {"name": obj.name}
        if obj.spec.outline is not None:              # 3D: the object's cells are drawn with the mesh
            r = obj.readout(model)[obj.name]
            c0 = np.asarray(r["position"]) - np.asarray(r["displacement"])
            a = r["rotation"]
            R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            entry["outline"] = (np.asarray(obj.spec.outline, float) - c0) @ R.T + np.asarray(r["position"])
        if pieces is not None:
            entry.update(forces_on(k))
        out.append(entry)
    for k in range(1, bodies if pieces is not None else 0):
        forces = forces_on(k)
        if len(forces["points"]):
            out.append({"name": pieces.pieces[k], **forces})
    return out


def soft_tags(tags: dict) -> list[int]:
    """The cell tags of the soft bodies among a mesh's named regions ("body", or "body:<name>" each)."""
    return [tag for name, tag in tags.items() if name == "body" or name.startswith("body:")]


class Snapshot(SimpleNamespace):
    """The whole state gathered in one place: what files and pictures are made from."""


def snapshot(model, to=(0,)) -> Snapshot | None:
    """The whole state on the ranks in `to` (collective; None on other ranks).

    Under MPI each rank holds its part of the mesh; nodes are matched by their
    input (Gmsh) numbers, so rank 0 gets the same arrays as a serial run, and
    sends them on to the other ranks in `to` (e.g. one that draws the picture
    while rank 0 writes the XDMF file).
    Returns a Snapshot with x (rest nodes), u (their displacement), cells,
    regions (tag per cell), cables (see cable_states), markers (name -> position).
    """
    comm = model.comm
    x, u, cells = vertex_displacements(model)
    n_cells = model.mesh.topology.index_map(model.mesh.topology.dim).size_local
    cells, regions = cells[:n_cells], cell_regions(model)
    cables = cable_states(model)
    markers = marker_positions(model)
    objects = object_states(model)
    contacts = contact_fields(model)
    if comm.size > 1:
        orig = np.asarray(model.mesh.geometry.input_global_indices, dtype=np.int64)
        parts = comm.gather((orig, x, u, orig[cells], regions, contacts), root=0)
        if comm.rank == 0:
            orig_all = np.concatenate([p[0] for p in parts])
            numbers, first = np.unique(orig_all, return_index=True)
            x = np.concatenate([p[1] for p in parts])[first]
            u = np.concatenate([p[2] for p in parts])[first]
            cells = np.searchsorted(numbers, np.concatenate([p[3] for p in parts]))
            regions = np.concatenate([p[4] for p in parts])
            if contacts is not None:        # a node a rank has only as a ghost carries its whole force too
                contacts = {k: np.concatenate([p[5][k] for p in parts])[first] for k in contacts}
    snap = Snapshot(x=x, u=u, cells=cells, regions=regions, cables=cables, markers=markers, objects=objects,
                    contact_fields=contacts,
                    body_tag=soft_tags(model.tm.tags)[0],
                    body_tags=soft_tags(model.tm.tags), tags=dict(model.tm.tags),
                    design=model.design) if comm.rank == 0 else None
    for rank in sorted(set(to) - {0}):
        if comm.rank == 0:
            comm.send(snap, dest=rank, tag=71)
        elif comm.rank == rank:
            snap = comm.recv(source=0, tag=71)
    return snap if comm.rank in to else None


def gathered_snapshot(state) -> Snapshot | None:
    """A Snapshot as it is, or the snapshot of a model (collective)."""
    return state if isinstance(state, Snapshot) else snapshot(state)


# -- files ------------------------------------------------------------------------------------------
def cell_gradients(x: np.ndarray, y: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Per simplex (triangle or tetrahedron through its vertices): F, the linear map of the rest cell x
    onto the deformed one y, (n, dim, dim) (exact for P1)."""
    A = np.stack([x[cells[:, k]] - x[cells[:, 0]] for k in range(1, cells.shape[1])], axis=2)
    B = np.stack([y[cells[:, k]] - y[cells[:, 0]] for k in range(1, cells.shape[1])], axis=2)
    return B @ small_inverses(A)


def small_inverses(A: np.ndarray) -> np.ndarray:
    """The inverse of every 2x2 or 3x3 matrix in (n, d, d), written out (adjugate over determinant).

    np.linalg.inv calls LAPACK once per matrix: 12-58 ms for finger.toml's 1,356 cells on a loaded
    two-core host, against well under a millisecond here. A singular matrix gives inf or nan, not an error.
    """
    d = A.shape[-1]
    if d == 2:
        a, b, c, e = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
        adj = np.stack([np.stack([e, -b], axis=-1), np.stack([-c, a], axis=-1)], axis=1)
    elif d == 3:
        r0, r1, r2 = A[:, 0], A[:, 1], A[:, 2]
        adj = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=2)  # columns: row crosses
    else:
        return np.linalg.inv(A)
    det = np.einsum("nij,nji->n", A, adj) / d                 # tr(A adj A) = d det A
    with np.errstate(divide="ignore", invalid="ignore"):
        return adj / det[:, None, None]


def largest_stretch(F: np.ndarray) -> np.ndarray:
    """sqrt(max eig(F^T F)) of every F in (n, dim, dim)."""
    return np.sqrt(np.linalg.eigvalsh(np.transpose(F, (0, 2, 1)) @ F)[:, -1])


STRETCH_CHUNK = 50_000     # cells per piece of cell_stretches (its scratch is 0.3 KB per cell of a piece)


def cell_stretches(x: np.ndarray, y: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The largest principal stretch of every cell mapped from rest x to deformed y, STRETCH_CHUNK cells at
    a time: about 15 MB of scratch, where the whole of arm3d's 2.8M cells at 1.43M DOFs took 0.8 GB."""
    cells = np.asarray(cells)
    out = np.empty(len(cells))
    for lo in range(0, len(cells), STRETCH_CHUNK):   # pieces of cells, not a loop over cells
        out[lo:lo + STRETCH_CHUNK] = largest_stretch(cell_gradients(x, y, cells[lo:lo + STRETCH_CHUNK]))
    return out


def write_xdmf(path: Path, state) -> None:
    """Mesh (rest coordinates) with displacement, region tag, largest principal stretch per cell, and
    cables as polylines; where bodies and objects can touch (or a body itself), the contact force (N), its normal and
    friction parts, the traction (MPa) and the stick/slip state on every node (contact_fields).

    `state` is a model (collective) or a Snapshot of one.

    Cables are extra points and line cells in the same grid, carrying their
    tension (each segment's: with friction it varies along the cable) and an id (the cable's position in the
    design), so a single file
    opens in ParaView (Warp By Vector on `displacement`) and in meshio.
    """
    snap = gathered_snapshot(state)
    if snap is None:
        return
    x, u, cells = snap.x, snap.u, snap.cells
    gdim = x.shape[1]
    cell_type = "triangle" if gdim == 2 else "tetra"
    points, disp = [x], [u]
    lines, tension, cable_id = [], [], []
    offset = len(x)
    for i, c in enumerate(snap.cables):
        n = len(c["rest"])
        points.append(c["rest"])
        disp.append(c["deformed"] - c["rest"])
        lines.append(offset + np.column_stack([np.arange(n - 1), np.arange(1, n)]))
        tension += list(c.get("tensions", [c["tension"]] * (n - 1)))
        cable_id += [i] * (n - 1)
        offset += n
    pts = np.vstack(points)
    if gdim == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    d = np.vstack(disp)
    d3 = np.column_stack([d, np.zeros(len(d))]) if gdim == 2 else d
    blocks = [(cell_type, cells)]
    region = [snap.regions.astype(float)]
    tens = [np.zeros(len(cells))]
    ids = [np.full(len(cells), -1.0)]
    stretch = [cell_stretches(x, x + u, cells)]
    if lines:
        blocks.append(("line", np.vstack(lines)))
        region.append(np.full(len(tension), -1.0))
        tens.append(np.asarray(tension, float))
        ids.append(np.asarray(cable_id, float))
        stretch.append(np.zeros(len(tension)))
    point_data = {"displacement": d3}
    if getattr(snap, "contact_fields", None) is not None:      # pieces that can touch: forces between them
        pad = len(pts) - len(x)
        for name, values in snap.contact_fields.items():
            if values.ndim == 1:
                point_data[name] = np.concatenate([values, np.zeros(pad)])
                continue
            v = np.vstack([values, np.zeros((pad, values.shape[1]))])
            point_data[name] = v if v.shape[1] == 3 else np.column_stack([v, np.zeros(len(pts))])
    cell_data = {"region": region, "tension": tens, "cable": ids, "stretch": stretch}
    atomic_write(path, lambda tmp: write_xml_grid(tmp, pts, blocks, point_data, cell_data))


_XDMF_CELLS = {"triangle": ("Triangle", 0x4), "tetra": ("Tetrahedron", 0x6), "line": ("Polyline", 0x2)}
XML_ROWS = 100_000            # rows of an array turned into text at a time


def _data_item(f, a: np.ndarray) -> None:
    """One inline DataItem, its text made XML_ROWS rows at a time (never the whole array as text)."""
    kind, fmt = ("Float", "%.16e") if a.dtype.kind == "f" else ("Int", "%d")
    f.write(f'<DataItem DataType="{kind}" Dimensions="{" ".join(map(str, a.shape))}" Format="XML" '
            f'Precision="8">\n'.encode())
    for lo in range(0, len(a), XML_ROWS):
        np.savetxt(f, a[lo:lo + XML_ROWS], fmt)
    f.write(b"</DataItem>")


def write_xml_grid(path, points: np.ndarray, blocks: list, point_data: dict, cell_data: dict) -> None:
    """One XDMF 3 grid with its data inline as text, written as it is made: meshio's
    ``xdmf.write(..., data_format="XML")`` layout, which holds the whole file as text in memory at once
    (0.4 KB per cell: 1.1 GB for arm3d's 2.8M cells at 1.43M DOFs); this takes a few MB of scratch.
    points (n, 3); blocks
    [(meshio cell type, (m, k) nodes)]; point_data {name: (n,) or (n, 3)}; cell_data {name: [one (m,)
    array per block]}."""
    with open(path, "wb") as f:
        f.write(b'<Xdmf Version="3.0"><Domain><Grid Name="Grid"><Geometry GeometryType="XYZ">')
        _data_item(f, np.asarray(points, dtype=float))
        f.write(b"</Geometry>")
        n_cells = sum(len(c) for _, c in blocks)
        if len(blocks) == 1:
            kind, cells = blocks[0]
            f.write(f'<Topology TopologyType="{_XDMF_CELLS[kind][0]}" NumberOfElements="{n_cells}" '
                    f'NodesPerElement="{cells.shape[1]}">'.encode())
            _data_item(f, np.asarray(cells, dtype=np.int64))
        else:   # each cell as its type's number (and a line's node count) followed by its nodes
            f.write(f'<Topology TopologyType="Mixed" NumberOfElements="{n_cells}">'.encode())
            rows = []
            for kind, c in blocks:
                head = [_XDMF_CELLS[kind][1]] + ([c.shape[1]] if kind == "line" else [])
                rows.append(np.column_stack([np.tile(head, (len(c), 1)), c]).ravel())
            _data_item(f, np.concatenate(rows).astype(np.int64))
        f.write(b"</Topology>")
        for center, data in (("Node", point_data), ("Cell", {k: np.concatenate(v) for k, v in cell_data.items()})):
            for name, a in data.items():
                kind = "Scalar" if a.ndim == 1 else "Vector"
                f.write(f'<Attribute Name="{name}" AttributeType="{kind}" Center="{center}">'.encode())
                _data_item(f, np.asarray(a, dtype=float))
                f.write(b"</Attribute>")
        f.write(b"</Grid></Domain></Xdmf>")


# -- runs in time (skelfem.fem.dynamics) -------------------------------------------------------------------
def _body_arrays(snap: Snapshot) -> tuple[np.ndarray, list, np.ndarray]:
    """(points, cell blocks, displacement) of a snapshot's mesh, padded to 3D as in solution.xdmf."""
    x, u = snap.x, snap.u
    if x.shape[1] == 2:
        x, u = np.column_stack([x, np.zeros(len(x))]), np.column_stack([u, np.zeros(len(u))])
    return x, [("triangle" if snap.x.shape[1] == 2 else "tetra", snap.cells)], u


class XdmfSeries:
    """trajectory.xdmf + trajectory.h5: the mesh once, the displacement at every step (rank 0 only).

    Every ``write`` appends the step's displacement to the HDF5 file at once;
    the small XML index that ParaView (and meshio's TimeSeriesReader) reads is
    written by ``close``. Open it in ParaView and press play; Warp By Vector on
    ``displacement`` shows the motion. The cables are not in it (meshio 5.0's
    time-series writer cannot mix line and volume cells); the GIF and
    trajectory.csv have them.
    """

    def __init__(self, path: Path, snap: Snapshot):
        import h5py
        from meshio.xdmf.time_series import TimeSeriesWriter

        path = Path(path)

        class _Writer(TimeSeriesWriter):            # meshio 5.0 puts the .h5 in the working folder
            def __enter__(self):
                self.h5_filename = str(path.with_suffix(".h5"))
                self.h5_file = h5py.File(self.h5_filename, "w")
                return self

        self.path = path
        self.writer = _Writer(str(path), data_format="HDF").__enter__()
        pts, blocks, _ = _body_arrays(snap)
        self.writer.write_points_cells(pts, blocks)
        self.region = [snap.regions.astype(float)]

    def write(self, t: float, snap: Snapshot) -> None:
        _, _, d = _body_arrays(snap)
        self.writer.write_data(float(t), point_data={"displacement": d}, cell_data={"region": self.region})
        self.writer.h5_file.flush()

    def close(self) -> None:
        self.writer.__exit__(None, None, None)


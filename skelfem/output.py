"""Results on disk: result.json, solution.xdmf (ParaView/meshio) and deformed.png.

Every file is written to a temporary name in the output folder and renamed
into place, so a reader never sees a half-written file. Only rank 0 writes.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np

FORMAT = 1


# -- small helpers ---------------------------------------------------------------------------
def say(*args, **kwargs) -> None:
    """print, on MPI rank 0 only (progress lines of studies and scripts)."""
    from mpi4py import MPI
    if MPI.COMM_WORLD.rank == 0:
        print(*args, **kwargs)


def atomic_write(path: Path, write) -> None:
    """Call write(tmp_path) and rename the result onto path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def copy_figure(picture: Path, folder: Path | None) -> None:
    """Copy a study's picture into folder (the README's figures), atomically; nothing if folder is None."""
    if folder is not None:
        data = Path(picture).read_bytes()
        atomic_write(Path(folder) / Path(picture).name, lambda tmp: Path(tmp).write_bytes(data))


def strict_json(value):
    """value with numpy types made plain and every non-finite float (NaN, +-Infinity) made None.

    JSON has no NaN or Infinity; Python's json module would write them anyway
    (and most readers then fail), so skelfem writes null instead.
    """
    if isinstance(value, dict):
        return {str(k): strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return [strict_json(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, data: dict) -> None:
    """data as strict JSON (non-finite numbers as null), atomically."""
    text = json.dumps(strict_json(data), indent=2, allow_nan=False) + "\n"

    def write(tmp):
        with open(tmp, "w") as f:
            f.write(text)
    atomic_write(path, write)


def write_text(path: Path, text: str) -> None:
    """A text file, atomically."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def write_csv(path: Path, fields, rows) -> None:
    """Rows (dicts) as CSV with the given columns (missing values empty), atomically."""
    import csv

    def write(tmp):
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, list(fields), extrasaction="ignore")
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k, "") for k in fields})
    atomic_write(path, write)


def _floats(a) -> list:
    return [float(v) for v in np.asarray(a, dtype=float).ravel()]


# -- the state as numbers ------------------------------------------------------------------------
def vertex_displacements(scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rest node coordinates, displacement at the nodes, triangles/tets) of the P1 geometry."""
    mesh, V = scene.mesh, scene.V
    tdim, gdim = mesh.topology.dim, mesh.geometry.dim
    x = mesh.geometry.x[:, :gdim]
    geo = mesh.geometry.dofmap.array.reshape(-1, tdim + 1)
    dofs = V.dofmap.list.array.reshape(len(geo), -1)[:, :tdim + 1]   # vertex DOFs come first
    node_dof = np.empty(len(x), dtype=np.int64)
    node_dof[geo.ravel()] = dofs.ravel()
    u = scene.u.x.array.reshape(-1, scene.bs)[node_dof]
    return x, u, geo


def cell_regions(scene) -> np.ndarray:
    """Tag value of every local cell (body = 1, bones after)."""
    n = scene.mesh.topology.index_map(scene.mesh.topology.dim).size_local
    tags = np.zeros(n, dtype=np.int32)
    ct = scene.tm.cell_tags
    owned = ct.indices < n
    tags[ct.indices[owned]] = ct.values[owned]
    return tags


def cable_states(model) -> list[dict]:
    u = model.u.x.array
    out = []
    for term in model.terms_in("cables"):
        c, L = term.cable, term.rest_length
        out.append({"name": c.name, "kind": c.kind, "rest": c.X, "deformed": c.positions(u),
                    "length": c.length(u), "rest_length": L, "tension": c.tension(u, L)})
    return out


def marker_positions(model) -> dict:
    """{name: current position} of the design's markers (collective under MPI)."""
    terms = model.terms_in("markers")
    if not terms:
        return {}
    return dict(zip(terms[0].names, terms[0].positions(model.u.x.array)))


class Snapshot(SimpleNamespace):
    """The whole state gathered in one place: what files and pictures are made from."""


def snapshot(scene, to=(0,)) -> Snapshot | None:
    """The whole state on the ranks in `to` (collective; None on other ranks).

    Under MPI each rank holds its part of the mesh; nodes are matched by their
    input (Gmsh) numbers, so rank 0 gets the same arrays as a serial run, and
    sends them on to the other ranks in `to` (e.g. one that draws the picture
    while rank 0 writes the XDMF file).
    Returns a Snapshot with x (rest nodes), u (their displacement), cells,
    regions (tag per cell), cables (see cable_states), markers (name -> position).
    """
    comm = scene.comm
    x, u, cells = vertex_displacements(scene)
    n_cells = scene.mesh.topology.index_map(scene.mesh.topology.dim).size_local
    cells, regions = cells[:n_cells], cell_regions(scene)
    cables = cable_states(scene)
    markers = marker_positions(scene)
    if comm.size > 1:
        orig = np.asarray(scene.mesh.geometry.input_global_indices, dtype=np.int64)
        parts = comm.gather((orig, x, u, orig[cells], regions), root=0)
        if comm.rank == 0:
            orig_all = np.concatenate([p[0] for p in parts])
            numbers, first = np.unique(orig_all, return_index=True)
            x = np.concatenate([p[1] for p in parts])[first]
            u = np.concatenate([p[2] for p in parts])[first]
            cells = np.searchsorted(numbers, np.concatenate([p[3] for p in parts]))
            regions = np.concatenate([p[4] for p in parts])
    snap = Snapshot(x=x, u=u, cells=cells, regions=regions, cables=cables, markers=markers,
                    body_tag=scene.tm.tags["body"], design=scene.design) if comm.rank == 0 else None
    for rank in sorted(set(to) - {0}):
        if comm.rank == 0:
            comm.send(snap, dest=rank, tag=71)
        elif comm.rank == rank:
            snap = comm.recv(source=0, tag=71)
    return snap if comm.rank in to else None


def _gathered(state) -> Snapshot | None:
    """A Snapshot as it is, or the snapshot of a model (collective)."""
    return state if isinstance(state, Snapshot) else snapshot(state)


# -- files ------------------------------------------------------------------------------------------
def write_xdmf(path: Path, scene) -> None:
    """Mesh (rest coordinates) with displacement, region tag, and cables as polylines.

    `scene` is a model (collective) or a Snapshot of one.

    Cables are extra points and line cells in the same grid, carrying their
    tension and an id (the cable's position in the design), so a single file
    opens in ParaView (Warp By Vector on `displacement`) and in meshio.
    """
    import meshio

    snap = _gathered(scene)
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
        tension += [c["tension"]] * (n - 1)
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
    if lines:
        blocks.append(("line", np.vstack(lines)))
        region.append(np.full(len(tension), -1.0))
        tens.append(np.asarray(tension, float))
        ids.append(np.asarray(cable_id, float))
    m = meshio.Mesh(pts, blocks, point_data={"displacement": d3},
                    cell_data={"region": region, "tension": tens, "cable": ids})
    atomic_write(path, lambda tmp: meshio.xdmf.write(tmp, m, data_format="XML"))


REGION_COLORS = {"body": "#f4b6a6", "bone": "#e8e4d8"}
CABLE_COLORS = {"tendon": "#1f5fbf", "ligament": "#d9822b"}


def plot_deformed(path: Path, scene, title: str = "", ax=None, show_rest: bool = True):
    """Rest outline, deformed mesh coloured by region, cables, markers and pins (2D)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    snap = _gathered(scene)
    if snap is None:
        return
    design = snap.design
    x, u, tri = snap.x, snap.u, snap.cells
    y = x + u
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(6, 7), dpi=120)
    regions = snap.regions
    body_tag = snap.body_tag
    colors = np.where(regions == body_tag, REGION_COLORS["body"], REGION_COLORS["bone"])
    ax.add_collection(PolyCollection(y[tri], facecolors=colors, edgecolors="#7a6a66",
                                     linewidths=0.15))
    if show_rest:
        loops = [design.body.outline, *design.body.holes, *(b.outline for b in design.bones)]
        for loop in loops:
            closed = np.vstack([loop, loop[:1]])
            ax.plot(closed[:, 0], closed[:, 1], color="0.55", lw=0.8, ls="--", zorder=1)
    for c in snap.cables:
        p = c["deformed"]
        lw = 1.2 + (1.5 if c["tension"] > 0 else 0.0)
        label = f"{c['name']} ({c['kind']}): {c['tension']:.3g} N"
        ax.plot(p[:, 0], p[:, 1], color=CABLE_COLORS[c["kind"]], lw=lw, zorder=3,
                ls="-" if c["tension"] > 0 else ":", label=label)
    for pin in design.pins:
        (x0, y0), (x1, y1) = pin.region
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, hatch="////",
                                   ec="0.3", lw=0.6, zorder=2))
    for g in design.grounds:
        t = np.array([-g.normal[1], g.normal[0]])
        ends = np.array([g.point - 1e3 * t, g.point + 1e3 * t])
        ax.plot(ends[:, 0], ends[:, 1], color="k", lw=1.5, zorder=2)
    if snap.markers:
        pos = np.array(list(snap.markers.values()))
        ax.plot(pos[:, 0], pos[:, 1], "o", color="#222222", ms=4, zorder=4)
        for name, p in snap.markers.items():
            ax.annotate(name, p, textcoords="offset points", xytext=(5, 5), fontsize=8)
    allpts = np.vstack([y, x]) if show_rest else y
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    if title:
        ax.set_title(title, fontsize=10)
    if snap.cables:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=2, fontsize=7, frameon=False)
    if own:
        fig.tight_layout()
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
        plt.close(fig)


def plot_deformed_3d(path: Path, scene, title: str = "", window_size=(900, 900),
                     points=(), paths=()) -> None:
    """Off-screen PNG of a 3D result: translucent body, opaque bones, cables, markers.

    `points` are extra (xyz, colour) dots (e.g. IK targets), `paths` extra
    ((n, 3) array, colour) polylines (e.g. a target path). Rendered with
    pyvista/VTK through EGL, so it needs no display.
    """
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    snap = _gathered(scene)
    if snap is None:
        return
    x, u, tets = snap.x, snap.u, snap.cells
    y = x + u
    regions = snap.regions
    body_tag = snap.body_tag
    cells = np.column_stack([np.full(len(tets), 4), tets]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8), y)
    grid.cell_data["region"] = regions
    rest = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8), x)
    p = pv.Plotter(off_screen=True, window_size=window_size)
    p.set_background("white")
    body = grid.extract_cells(np.flatnonzero(regions == body_tag)).extract_surface(algorithm=None)
    p.add_mesh(rest.extract_surface(algorithm=None).extract_feature_edges(30.0), color="#888888", line_width=1.0)
    p.add_mesh(body, color=REGION_COLORS["body"], opacity=0.35, show_edges=False)
    bones = np.flatnonzero(regions != body_tag)
    if len(bones):
        p.add_mesh(grid.extract_cells(bones).extract_surface(algorithm=None), color=REGION_COLORS["bone"],
                   show_edges=True, edge_color="#9a9080", line_width=0.3)
    for c in snap.cables:
        line = pv.lines_from_points(c["deformed"])
        width = 5 if c["tension"] > 0 else 2
        p.add_mesh(line, color=CABLE_COLORS[c["kind"]], line_width=width, render_lines_as_tubes=True)
    if snap.markers:
        pos = np.array(list(snap.markers.values()))
        p.add_point_labels(pos, list(snap.markers), point_size=12, font_size=14, point_color="#222222",
                           shape=None, always_visible=True)
    for xyz, colour in points:
        p.add_mesh(pv.PolyData(np.atleast_2d(np.asarray(xyz, float))), color=colour, point_size=16,
                   render_points_as_spheres=True)
    for pts, colour in paths:
        p.add_mesh(pv.lines_from_points(np.asarray(pts, float)), color=colour, line_width=4)
    if title:
        p.add_text(title, font_size=11, color="black")
    p.add_axes(color="black")
    extent = np.ptp(x, axis=0)
    if extent[2] < 0.5 * extent[:2].max():   # a slab (extruded 2D design) bends in x-y: look along z
        p.view_xy()
        p.camera.Elevation(-20)
        p.camera.Azimuth(25)
    else:
        p.view_isometric()
    p.reset_camera()
    atomic_write(path, lambda tmp: p.screenshot(tmp))
    p.close()


# -- tracking pictures (ik, track, the IK study) ---------------------------------------------------
TARGET_COLOR, ACHIEVED_COLOR = "#d62728", "#2ca02c"


def include_points(ax, points: np.ndarray, pad: float = 3.0) -> None:
    """Widen the axis limits to show points."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    lo, hi = points[:, :2].min(axis=0) - pad, points[:, :2].max(axis=0) + pad
    ax.set_xlim(min(x0, lo[0]), max(x1, hi[0]))
    ax.set_ylim(min(y0, lo[1]), max(y1, hi[1]))


def plot_poses(ax, model, poses: list, alpha: float = 0.3) -> None:
    """Deformed poses (local DOF arrays) drawn faded on one axis; model.u is restored after."""
    from matplotlib.legend import Legend

    keep = model.u.x.array.copy()
    lims = []
    for i, pose in enumerate(poses):
        model.u.x.array[:] = pose
        before = set(ax.get_children())
        plot_deformed(None, model, ax=ax, show_rest=(i == 0))
        for artist in set(ax.get_children()) - before:
            if hasattr(artist, "set_alpha") and not isinstance(artist, Legend):
                artist.set_alpha(alpha if i < len(poses) - 1 else min(1.0, 2 * alpha))
        lims.append((*ax.get_xlim(), *ax.get_ylim()))
    model.u.x.array[:] = keep
    if lims:
        lims = np.array(lims)
        ax.set_xlim(lims[:, 0].min(), lims[:, 1].max())
        ax.set_ylim(lims[:, 2].min(), lims[:, 3].max())


def draw_track(ax, model, results, poses: list, title: str = "") -> None:
    """Target and achieved paths over a few faded deformed poses, on one axis."""
    plot_poses(ax, model, poses)
    if ax.get_legend() is not None:
        ax.get_legend().remove()                # the cables' legend: too long for several poses
    target = np.array([r.target for r in results])
    achieved = np.array([r.position for r in results])
    h1, = ax.plot(target[:, 0], target[:, 1], "x--", color=TARGET_COLOR, ms=5, lw=1, zorder=6, label="target")
    h2, = ax.plot(achieved[:, 0], achieved[:, 1], "o-", color=ACHIEVED_COLOR, ms=3, lw=1.2, zorder=7,
                  mfc="none", label="achieved")
    include_points(ax, np.vstack([target, achieved]))
    ax.legend(handles=[h1, h2], loc="upper right", fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)


# -- runs in time (skelfem.dynamics) -------------------------------------------------------------------
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


def write_motion_gif(path: Path, frames: list, title: str = "", fps: int = 20) -> None:
    """An animated GIF of 2D snapshots [(t, Snapshot)], axes fixed over the motion (Pillow writer)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    allpts = np.vstack([np.vstack([s.x + s.u, s.x]) for _, s in frames])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    fig, ax = plt.subplots(figsize=(5, 5.5), dpi=80)

    def draw(i):
        ax.clear()
        t, snap = frames[i]
        plot_deformed(None, snap, f"{title}  t = {t:.4g} s", ax=ax)
        if ax.get_legend() is not None:
            ax.get_legend().remove()
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        return []

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
    atomic_write(path, lambda tmp: anim.save(tmp, writer=PillowWriter(fps=fps)))
    plt.close(fig)

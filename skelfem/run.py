"""One static simulation, from a validated design to files on disk.

Shared by ``skelfem simulate`` (on COMM_WORLD) and ``skelfem sweep`` (one
sub-communicator per case). Raises DesignError / MeshingError for bad input;
a solve that fails is reported in the result (``converged: false``), never
as an equilibrium.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

log = logging.getLogger("skelfem")

STALE = ("solution.xdmf", "solution.h5", "deformed.png")


def build_scene(design, comm):
    """Mesh the design on comm and bind it to a Scene; returns (scene, timings)."""
    from .geometry import mesh_design
    from .scene import Scene

    t0 = time.perf_counter()
    tm = mesh_design(design, comm)
    t1 = time.perf_counter()
    scene = Scene(design, tm)
    return scene, {"mesh": t1 - t0, "compile": time.perf_counter() - t1}


def solve(design, scene, timings: dict):
    """Newton with load stepping as [solver] asks; returns (report, solver)."""
    from .solver import NewtonSolver

    t0 = time.perf_counter()
    solver = NewtonSolver(scene, design.solver)
    timings["compile"] += time.perf_counter() - t0
    log.info("%s: %d DOFs, %d cells; solving in %d load step(s)", design.name,
             scene.V.dofmap.index_map.size_global * scene.bs,
             scene.mesh.topology.index_map(scene.mesh.topology.dim).size_global, design.solver.steps)
    t1 = time.perf_counter()
    report = solver.solve(design.solver.steps)
    timings["solve"] = time.perf_counter() - t1
    return report, solver


def picture_title(design) -> str:
    pulled = [f"{c.name} u={c.contraction:g} mm" for c in design.cables
              if c.kind == "tendon" and c.contraction > 0]
    return f"{design.name}: " + (", ".join(pulled) if pulled else "no contraction")


def write_results(design, scene, report, out: Path, timings: dict, t0: float,
                  picture: bool = True, extra: dict | None = None) -> dict:
    """result.json always; solution.xdmf and deformed.png only for an equilibrium."""
    from .output import plot_deformed, plot_deformed_3d, result_dict, write_json, write_xdmf

    comm = scene.comm
    timings["total"] = time.perf_counter() - t0
    result = result_dict(design, scene, report, timings)
    result.update(extra or {})
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        for stale in STALE:
            (out / stale).unlink(missing_ok=True)   # never leave an old equilibrium beside a new result
    if report.converged:                         # collective: every rank takes part, rank 0 writes
        write_xdmf(out / "solution.xdmf", scene)
        if picture:
            plot = plot_deformed if design.dim == 2 else plot_deformed_3d
            plot(out / "deformed.png", scene, picture_title(design))
    result["timings"]["total"] = round(time.perf_counter() - t0, 4)
    if comm.rank == 0:
        write_json(out / "result.json", result)
    return result


def simulate_design(design, out: Path, comm, picture: bool = True, extra: dict | None = None) -> dict:
    """Mesh, solve and write one design on comm; returns the result dict."""
    t0 = time.perf_counter()
    scene, timings = build_scene(design, comm)
    report, _ = solve(design, scene, timings)
    return write_results(design, scene, report, Path(out), timings, t0, picture, extra)

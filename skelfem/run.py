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

def open_session(design, comm):
    """Mesh the design on comm and compile its model: a Session ready to solve."""
    from .session import Session
    return Session(design, comm=comm)


def picture_title(design) -> str:
    pulled = [f"{c.name} u={c.contraction:g} mm" for c in design.cables
              if c.kind == "tendon" and c.contraction > 0]
    return f"{design.name}: " + (", ".join(pulled) if pulled else "no contraction")


def write_results(session, result, out: Path, t0: float, picture: bool = True,
                  extra: dict | None = None) -> dict:
    """result.json always; solution.xdmf and deformed.png only for an equilibrium."""
    from .outdir import publish
    from .output import plot_deformed, plot_deformed_3d, snapshot, write_json, write_xdmf

    design, model = session.design, session.model
    comm = model.comm
    data = result.to_dict()
    data.update(extra or {})
    # staged beside `out` and swapped in whole (skelfem.outdir): the folder holds the old
    # complete result until the new one is complete, never a mix of the two
    with publish(out, comm) as stage:
        if result.converged:
            # one gather; under MPI the last rank draws the picture while rank 0 writes the XDMF
            painter = comm.size - 1 if picture else 0
            snap = snapshot(model, to=(0, painter))
            if comm.rank == 0:
                stage.run(write_xdmf, stage.path / "solution.xdmf", snap)
            if picture and comm.rank == painter:
                plot = plot_deformed if design.dim == 2 else plot_deformed_3d
                stage.run(plot, stage.path / "deformed.png", snap, picture_title(design))
        if comm.size > 1:
            comm.Barrier()                       # the total includes the picture
        data["timings"]["total"] = round(time.perf_counter() - t0, 4)
        if comm.rank == 0:
            stage.run(write_json, stage.path / "result.json", data)
    return data


def simulate_design(design, out: Path, comm, picture: bool = True, extra: dict | None = None) -> dict:
    """Mesh, solve and write one design on comm; returns the result dict."""
    t0 = time.perf_counter()
    with open_session(design, comm) as session:
        result = session.solve()
        return write_results(session, result, Path(out), t0, picture, extra)

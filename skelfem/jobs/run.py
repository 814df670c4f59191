"""One simulation, from a validated design to files on disk: static, or in time with [dynamics].

Shared by ``skelfem simulate`` (on COMM_WORLD) and ``skelfem sweep`` (one
sub-communicator per case). Raises DesignError / MeshingError for bad input;
a solve that fails is reported in the result (``converged: false``), never
as an equilibrium.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

log = logging.getLogger("skelfem")


def open_session(design, comm):
    """Mesh the design on comm and compile its model: a Session ready to solve."""
    from ..session import Session
    return Session(design, comm=comm)


def picture_title(design) -> str:
    pulled = [f"{c.name} u={c.contraction:g} mm" for c in design.cables
              if c.kind == "tendon" and c.contraction > 0]
    return f"{design.name}: " + (", ".join(pulled) if pulled else "no contraction")


def write_results(session, result, out: Path, t0: float, picture: bool = True,
                  extra: dict | None = None) -> dict:
    """result.json always; solution.xdmf and deformed.png only for an equilibrium."""
    from ..io.outdir import publish
    from ..io.files import write_json

    comm = session.model.comm
    data = result.to_dict()
    data.update(extra or {})
    # staged beside `out` and swapped in whole (skelfem.io.outdir): the folder holds the old
    # complete result until the new one is complete, never a mix of the two
    with publish(out, comm) as stage:
        if result.converged:
            # one gather; under MPI the last rank draws the picture while rank 0 writes the XDMF
            _write_equilibrium(stage, session, picture, comm.size - 1 if picture else 0)
        if comm.size > 1:
            comm.Barrier()                       # the total includes the picture
        data["timings"]["total"] = round(time.perf_counter() - t0, 4)
        if comm.rank == 0:
            stage.run(write_json, stage.path / "result.json", data)
    return data


def write_staged_results(session, out: Path, t0: float, picture: bool = True, extra: dict | None = None) -> dict:
    """Run the design's [[stages]] (Session.run_stages) and write its results, all or nothing.

    result.json always (``stages``: one entry per stage run); stages.xdmf/.h5, one frame per completed
    stage (time = the stage's number, 1, 2, ...), and deformed-STAGE.png of each; solution.xdmf and
    deformed.png of the last stage when every stage converged. A stage that fails ends the run: the
    completed stages' frames and pictures are kept.
    """
    from ..io.outdir import publish
    from ..io.xdmf import XdmfSeries, snapshot
    from ..io.files import write_json

    design, model = session.design, session.model
    comm = model.comm
    painter = comm.size - 1 if picture else 0
    with publish(out, comm) as stage:
        frames = {"series": None, "count": 0}

        def on_stage(spec, result):
            if not result.converged:
                return
            snap = snapshot(session.model, to=(0, painter))      # collective
            frames["count"] += 1
            if comm.rank == 0:
                if frames["series"] is None:
                    frames["series"] = stage.run(XdmfSeries, stage.path / "stages.xdmf", snap)
                if frames["series"] is not None:
                    stage.run(frames["series"].write, float(frames["count"]), snap)
            if picture and comm.rank == painter:
                stage.run(_picture, stage.path / f"deformed-{spec.name}.png", snap, design,
                          f"{design.name}, stage {spec.name}")

        result = session.run_stages(on_stage)
        if comm.rank == 0 and frames["series"] is not None:
            stage.run(frames["series"].close)
        data = result.to_dict()
        data.update(extra or {})
        if result.converged:
            _write_equilibrium(stage, session, picture, painter)
        if comm.size > 1:
            comm.Barrier()
        data["timings"]["total"] = round(time.perf_counter() - t0, 4)
        if comm.rank == 0:
            stage.run(write_json, stage.path / "result.json", data)
    return data


def _picture(path: Path, snap, design, title: str) -> None:
    from ..viz.plots import plot_deformed, plot_deformed_3d
    (plot_deformed if design.dim == 2 else plot_deformed_3d)(path, snap, title)


def _write_equilibrium(stage, session, picture: bool, painter: int) -> None:
    """solution.xdmf (rank 0) and deformed.png (rank painter) of the session's state (collective)."""
    from ..io.xdmf import snapshot, write_xdmf
    design, comm = session.design, session.model.comm
    snap = snapshot(session.model, to=(0, painter))
    if comm.rank == 0:
        stage.run(write_xdmf, stage.path / "solution.xdmf", snap)
    if picture and comm.rank == painter:
        stage.run(_picture, stage.path / "deformed.png", snap, design, picture_title(design))


def simulate_design(design, out: Path, comm, picture: bool = True, extra: dict | None = None) -> dict:
    """Mesh, solve (every stage in order, if the design has [[stages]]) and write one design on comm;
    returns the result dict."""
    t0 = time.perf_counter()
    with open_session(design, comm) as session:
        if design.stages:
            return write_staged_results(session, Path(out), t0, picture, extra)
        result = session.solve()
        return write_results(session, result, Path(out), t0, picture, extra)


MAX_GIF_FRAMES = 80


class ProgressBar:
    """A one-line progress bar on stderr (rank 0) for runs longer than `after` seconds.

    On a terminal the line is redrawn in place; otherwise (a log file) one line
    is printed per tenth of the run.
    """

    def __init__(self, label: str, after: float = 2.0, stream=None):
        import sys
        from mpi4py import MPI
        self.label, self.after = label, after
        self.stream = stream or sys.stderr
        self.on = MPI.COMM_WORLD.rank == 0
        self.tty = self.on and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.shown, self.last, self.tenth = False, 0.0, 0

    def __call__(self, fraction: float) -> None:
        now = time.perf_counter()
        if not self.on or now - self.t0 < self.after:
            return
        fraction = min(max(fraction, 0.0), 1.0)
        try:
            if self.tty:
                if now - self.last < 0.2 and fraction < 1.0:
                    return
                width = 30
                filled = int(round(width * fraction))
                eta = (now - self.t0) * (1.0 - fraction) / fraction if fraction > 0 else float("nan")
                self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (width - filled)}] "
                                  f"{100 * fraction:5.1f} %  {now - self.t0:6.1f} s, about {eta:5.0f} s left ")
                self.stream.flush()
            elif int(10 * fraction) > self.tenth:
                self.tenth = int(10 * fraction)
                self.stream.write(f"{self.label}: {100 * fraction:.0f} % ({now - self.t0:.1f} s)\n")
                self.stream.flush()
            self.shown, self.last = True, now
        except (OSError, ValueError):
            self.on = False

    def close(self) -> None:
        if self.on and self.tty and self.shown:
            try:
                self.stream.write("\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass


def write_dynamic_results(session, out: Path, t0: float, picture: bool = True, progress=None,
                          extra: dict | None = None) -> dict:
    """Run a design with [dynamics] in time and write its results, all or nothing.

    trajectory.xdmf/.h5 (the displacement at every step, written as the run
    goes), trajectory.csv (markers, tensions and energies per step),
    motion.gif (2D: up to MAX_GIF_FRAMES frames) and result.json, staged
    beside `out` and swapped in whole when every file is complete.
    """
    from ..fem.dynamics import trajectory_columns
    from ..io.outdir import publish
    from ..io.xdmf import XdmfSeries, snapshot
    from ..io.files import CsvStream, write_json
    from ..viz.animation import write_motion_gif

    design, model = session.design, session.model
    comm = model.comm
    spec = design.dynamics
    every = max(1, int(np.ceil(spec.steps / MAX_GIF_FRAMES)))
    gif = picture and design.dim == 2
    spent = {"write_xdmf": 0.0, "write_csv": 0.0, "write_gif": 0.0}    # s, each output's own cost
    with publish(out, comm) as stage:
        series, frames, rows = None, [], None
        if comm.rank == 0:                             # every row streamed as it is made
            rows = stage.run(CsvStream, stage.path / "trajectory.csv", trajectory_columns(design))

        def on_step(t, report):
            nonlocal series
            snap = snapshot(model)                     # collective; None off rank 0
            if comm.rank != 0:
                return
            tw = time.perf_counter()
            if rows is not None:
                stage.run(rows.write, report.trajectory[-1])
            spent["write_csv"] += time.perf_counter() - tw
            tw = time.perf_counter()
            if series is None:
                series = stage.run(XdmfSeries, stage.path / "trajectory.xdmf", snap)
            if series is not None:
                stage.run(series.write, t, snap)
            spent["write_xdmf"] += time.perf_counter() - tw
            n = report.load_steps
            if gif and (n % every == 0 or abs(t - spec.duration) <= 1e-9 * spec.duration):
                frames.append((t, snap))

        try:
            result = session.run_in_time(on_step, progress)
        finally:
            if rows is not None:
                rows.close()
        data = result.to_dict()
        data.update(extra or {})
        if comm.rank == 0:
            tw = time.perf_counter()
            if series is not None:
                stage.run(series.close)
            spent["write_xdmf"] += time.perf_counter() - tw
            tw = time.perf_counter()
            if rows is not None:
                stage.run(rows.close)
            spent["write_csv"] += time.perf_counter() - tw
            tw = time.perf_counter()
            if gif and frames:
                stage.run(write_motion_gif, stage.path / "motion.gif", frames, design.name)
            spent["write_gif"] = time.perf_counter() - tw
        data["timings"].update({k: round(v, 4) for k, v in spent.items()})
        if comm.size > 1:
            comm.Barrier()
        data["timings"]["total"] = round(time.perf_counter() - t0, 4)
        if comm.rank == 0:
            stage.run(write_json, stage.path / "result.json", data)
    return data

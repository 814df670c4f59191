"""A live simulation: a design kept meshed, compiled and factorised between solves.

    from skelfem import Session
    with Session("geometry/finger.toml") as s:       # a path, a design dict or a Design
        r = s.solve()                               # a Result; r.to_dict() is result.json
        s.set({"cables.flexor.contraction": 9.0})   # live parameters: no re-mesh, no recompile
        r = s.solve()                               # warm start from the last equilibrium
        s.edit(new_design_dict)                     # re-mesh; the last solution is the start

``set`` takes the ``--set`` keys. Keys that a term exposes as a parameter
(contractions, pretensions, stiffnesses, loads, pin moves, E and nu, ground
points, gravity, tractions...) change in place; any other key (mesh size,
outlines, cable paths...) re-meshes as ``edit`` does. Either way the new
design is validated first and a bad key or value raises the same one-line
DesignError as the CLI, leaving the session as it was.

Every user of the pipeline goes through this class: the CLI, sweeps,
IK and tracking, bench, studies and tests.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from .design.spec import Design, DesignError
from .fem.report import BUDGET_SPENT
from .result import Result, Status, plain as _plain, result_dict  # noqa: F401 (Result re-exported)
from .design.parse import changed_keys, flatten, live_value, load_design, parse_design
from .runtime import memory

log = logging.getLogger("skelfem")
# result.json's keys that describe the run, not a stage: left out of each entry of ``stages``
STAGE_LEFT_OUT = ("format", "design", "dofs", "cells", "degree", "linear_solver", "attempts", "residual_history",
                  "linear_iterations", "linear_fallbacks", "linear_loose_steps")
CARRY_CHUNK = 20_000      # new nodes located in the old mesh at a time when an edit carries the solution over


def _toml(value) -> str:
    """A Python value as TOML text (floats at full precision)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):      # a TOML basic string: control characters as \uXXXX escapes
        return '"' + "".join(f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7f else
                             "\\\\" if c == "\\" else '\\"' if c == '"' else c for c in value) + '"'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml(str(k))} = {_toml(v)}" for k, v in value.items()) + "}"
    raise DesignError(f"cannot use {value!r} as a design value")


def as_design(design, overrides=()) -> Design:
    """A validated Design from a path, a dict of the TOML's keys or a Design, with --set overrides."""
    overrides = list(overrides)
    if isinstance(design, Design):
        return parse_design(design.raw, design.source, overrides) if overrides else design
    if isinstance(design, dict):
        return parse_design(design, "<design>", overrides)
    return load_design(design, overrides)


class SessionError(RuntimeError):
    """A Session used after close, or from a second thread while another is inside it."""


def _exclusive(method):
    """One thread at a time inside a Session, and none after close: a second thread gets a clear
    SessionError at once instead of another thread's answers or a broken PETSc state."""
    import functools

    @functools.wraps(method)
    def guarded(self, *args, **kwargs):
        if not self._lock.acquire(blocking=False):
            raise SessionError(f"{self.design.name}: this Session is busy in another thread "
                               "(a Session is used by one thread at a time; make one per thread)")
        try:
            if self._closed:
                raise SessionError(f"{self.design.name}: this Session is closed")
            return method(self, *args, **kwargs)
        finally:
            self._lock.release()
    return guarded


class Session:
    """A design bound to a mesh, a model and a Newton solver, kept alive between solves.

    One thread at a time may be inside it (a second one gets a SessionError), and after ``close``
    every call but ``close`` raises SessionError. A failed ``set`` or ``edit`` leaves the session as
    it was: the old design, mesh, model and solution.
    """

    def __init__(self, design, overrides=(), comm=None):
        import threading

        from mpi4py import MPI
        self._lock, self._closed = threading.RLock(), False
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.design = as_design(design, overrides)
        self.model = self.solver = None
        self.solved = False
        self.size = None                # the SizeField the mesh was made with (skelfem.accuracy.adapt), or None
        self.timings: dict = {}
        self._build()

    # -- building -----------------------------------------------------------------------------
    def _build(self, tm=None) -> None:
        """A model and solver for self.design on tm (default: a new mesh of the design); the old ones,
        if any, are destroyed (an edit that re-meshes destroys the old solver first and keeps the old
        model until the solution is carried over)."""
        from .mesh.geometry import mesh_design
        from .fem.model import Model
        from .fem.newton import NewtonSolver

        t0 = time.perf_counter()
        fresh = tm is None
        if fresh:
            tm = mesh_design(self.design, self.comm, size=self.size)
        t1 = time.perf_counter()
        model = Model(self.design, tm)
        memory.release(model.num_cells)   # the build's scratch (facets, patterns) back to the system
        solver = NewtonSolver(model, self.design.solver)
        if self.solver is not None:
            self.solver.destroy()
            self._release(self.model)
        self.model, self.solver, self.solved = model, solver, False
        if fresh:
            self._meshed = self.design                        # the design the mesh was made for
            self._morph: Any = None                           # Morph of that mesh, made on the first move
        self.timings = {"mesh": t1 - t0, "compile": time.perf_counter() - t1}

    @staticmethod
    def _release(model) -> None:
        """Destroy the PETSc vectors DOLFINx made for a model being dropped (see fem.release.release_vectors)."""
        from .fem.release import release_vectors
        if model is not None:
            release_vectors(model)

    @property
    def dofs(self) -> int:
        return int(self.model.V.dofmap.index_map.size_global * self.model.bs)

    # -- changing the design ---------------------------------------------------------------------
    @_exclusive
    def set(self, changes: dict, design: Design | None = None) -> None:
        """Apply ``{--set key: value}``: live parameters in place, anything else by re-meshing.

        design: the validated Design these changes lead to, when the caller
        has it already (the editor does): it is not parsed again.
        """
        if design is None:
            design = parse_design(self.design.raw, self.design.source, self._overrides(changes))
        live = self.model.parameters()
        values = {key: live_value(design.raw, key, live[key]) if key in live else None for key in changes}
        if not all(values[key] is not None or self._run_setting(key, design) for key in changes):
            self.edit(design)
            return
        for key, value in values.items():
            if value is not None:
                self.model.set_parameter(key, value)
        self.design = design

    def _overrides(self, changes: dict) -> list:
        """``KEY=VALUE`` strings of changes; a key that is no dotted name or a value TOML cannot hold is a
        DesignError naming it."""
        source, out = self.design.source, []
        if not isinstance(changes, dict):
            raise DesignError(f"{source}: the changes must be a dict of --set keys and values, "
                              f"got {type(changes).__name__}")
        for key, value in changes.items():
            if not isinstance(key, str) or not key.strip() or "=" in key:
                raise DesignError(f"{source}: {key!r}: a --set key is a dotted name (cables.flexor.contraction)")
            try:
                out.append(f"{key}={_toml(value)}")
            except DesignError as exc:
                raise DesignError(f"{source}: {key}: {exc}") from None
        return out

    def _run_setting(self, key: str, design) -> bool:
        """Whether key only changes how a run steps (dt, schedules...), not the compiled model."""
        if not (key.startswith("dynamics.") or key.endswith(".schedule")):
            return False
        try:
            inertia = self.model.term("dynamics")
        except KeyError:
            return False               # the model has no inertia term: re-mesh and build one
        return design.dynamics is not None and \
            inertia.stiffness_damping == (design.dynamics.damping_stiffness > 0.0)

    @_exclusive
    def edit(self, design, overrides=(), morph: bool = False, size=None, preview: bool = False,
             moved_only: bool = False) -> str:
        """Replace the design (a path, a dict or a Design); the last solution is the start.

        The design is re-meshed, unless its mesh would be the same: when the
        outlines, holes, bones and mesh size are those the current mesh was
        made for (a cable, marker, pin or material edit), the mesh is kept.
        morph=True (the editor's drafts while dragging) also keeps the mesh
        when only polygon vertices moved, moving its nodes with them
        (:mod:`skelfem.mesh.morph`), if the moved mesh stays good; otherwise it re-meshes.
        On a kept mesh the model follows in place where it can (Model.refresh:
        no form compiled, matrix and solver kept).
        size: a non-uniform mesh size (skelfem.mesh.geometry.SizeField) below the
        design's [mesh] size: always re-meshes; the mesh of any later edit
        without it is uniform again.
        preview=True (the editor's 3D drafts): on moved nodes, cables and markers that only bones' poses
        moved keep their points in the cells they were found in instead of being built again (the state
        is a preview; skelfem.terms.base.bone_poses_only).
        moved_only=True: where the mesh cannot follow, nothing changes and "not moved" is returned (the
        editor's drafts whose bones' places only the moved tetrahedra checked: parse_design's poses_of).
        Returns how: "re-meshed", "same mesh", "moved nodes" or "not moved".
        """
        design = as_design(design, overrides)
        from .fem.newton import NewtonSolver
        x = self._same_mesh(design, morph) if size is None and self.size is None else None
        if x is not None:
            self._move_mesh(design, x, preview)
            return "moved nodes" if morph and np.any(x != self._morph.X0) else "same mesh"
        if moved_only:
            return "not moved"
        old_model, old_solved = self.model, self.solved
        start = None
        # the same outlines on a new mesh (a --tol ladder's next level): friction's history (anchors on the
        # old boundary) cannot follow, so a path-dependent design solves its load path from rest again, as
        # skelfem simulate does; an edited outline starts from the carried-over state as any edit
        from .mesh.morph import same_polygons
        if old_solved and self.comm.size == 1 and not (old_model.path_dependent and same_polygons(design, self.design)):
            start = (old_model.V.tabulate_dof_coordinates()[:, :old_model.dim].copy(),
                     old_model.u.x.array.reshape(-1, old_model.bs).copy(), old_model)
        # the old solver goes first: its matrix and multigrid or factorisation beside the new model were the
        # peak of a 3D ladder's last level (post3d's 682k P2 reference: 1.78 GB at the new model's build)
        self.solver.destroy()
        saved = (self.design, self.size, self.model, None, self.solved, self._meshed, self._morph,
                 self.timings)
        self.solver = None
        try:
            self.design, self.size = design, size
            self._build()
            if start is not None:
                self._carry_over(*start)
                self.solved = True
        except BaseException:                    # as it was: the old design, mesh, model and solution
            if self.solver is not None:          # the new model was built: it goes
                self.solver.destroy()
                self._release(self.model)
            (self.design, self.size, self.model, self.solver, self.solved, self._meshed, self._morph,
             self.timings) = saved
            self.solver = NewtonSolver(old_model, self.design.solver)    # a new one: the old is gone
            raise
        self._release(old_model)
        return "re-meshed"

    def _same_mesh(self, design, morph: bool) -> np.ndarray | None:
        """Node coordinates of the current mesh fit for design (see edit), or None to re-mesh."""
        from .mesh.geometry import region_names
        from .mesh.morph import Morph, same_polygons
        meshed = self._meshed
        if design.dim == 3:
            return self._same_mesh3d(design, morph)
        if (self.comm.size != 1 or design.dim != 2 or self.model is None
                or float(design.mesh.size) != float(meshed.mesh.size)
                or int(design.mesh.degree) != int(self.design.mesh.degree)):
            return None
        if region_names(design) != region_names(meshed):   # the mesh's regions are tagged by name
            return None
        if not morph:                   # the polygons as meshed, or a new mesh (no Morph needed to tell)
            if not same_polygons(design, meshed):
                return None
            return self._morph.X0 if self._morph is not None else self.model.mesh.geometry.x[:, :2].copy()
        if self._morph is None:
            self._morph = Morph(self.model.tm, meshed)
        return self._morph.moved(design)

    def _same_mesh3d(self, design, morph: bool) -> np.ndarray | None:
        """_same_mesh for a 3D design: the solids as meshed, the bones' poses moved (skelfem.mesh.morph3d)."""
        from .mesh.geometry import region_names
        from .mesh.morph3d import Morph3D, same_poses, shape_key
        meshed = self._meshed
        if (self.comm.size != 1 or self.model is None or meshed.dim != 3
                or float(design.mesh.size) != float(meshed.mesh.size)
                or int(design.mesh.degree) != int(self.design.mesh.degree)
                or region_names(design) != region_names(meshed) or shape_key(design) != shape_key(meshed)):
            return None
        if not morph:
            if not same_poses(design, meshed):
                return None
            return self._morph.X0 if self._morph is not None else self.model.mesh.geometry.x[:, :3].copy()
        if self._morph is None:
            self._morph = Morph3D(self.model.tm, meshed)
        return self._morph.moved(design)

    def prepare_moves(self) -> None:
        """Build now what a drag on this 3D mesh needs (its Morph3D: the Laplacian factorised, 1.3 s at 48k DOFs),
        so that the drag's first frame does not pay it; nothing in 2D (a 2D Morph is cheap) or once built."""
        from .mesh.morph3d import Morph3D
        if self.design.dim == 3 and self._morph is None and self.comm.size == 1 and self.model is not None \
                and self._meshed.dim == 3:
            self._morph = Morph3D(self.model.tm, self._meshed)

    def _move_mesh(self, design, x: np.ndarray, preview: bool = False) -> None:
        """The model for design on the current mesh with node coordinates x; u carries over as is.

        The model follows in place when it can (Model.refresh: compiled forms,
        matrix and factorisation kept); otherwise it is built anew on the mesh.
        """
        old_design, old_x = self.design, self.model.mesh.geometry.x[:, :x.shape[1]].copy()
        u = self.model.u.x.array.copy() if self.solved else None
        if self._morph is not None:     # else the nodes are where Gmsh put them, and x is that
            self._morph.apply(x)
        self.design = design
        try:
            if not self._refresh(design, preview):
                self._build(self.model.tm)
        except BaseException:
            if self._morph is not None:
                self._morph.apply(old_x)
            self.design = old_design
            raise
        if u is not None:
            self.model.u.x.array[:] = u
            self.model.set_factor(1.0)
            self.model.carry_over(self.model.u.vector)         # bones: their best rigid motion
            self.model.apply_bcs(self.model.u.vector)
            self.solved = True

    def _refresh(self, design, preview: bool = False) -> bool:
        """Let the model follow design in place (a new matrix if its pattern grew); False if it cannot."""
        t0 = time.perf_counter()
        changed = changed_keys(flatten(self.model.design.raw), flatten(design.raw))
        if preview and changed:
            from .terms.base import PREVIEW
            changed = set(changed) | {PREVIEW}               # the terms may follow as a preview allows
        if any(k.startswith(("solver.", "contact.")) for k in changed):    # the solver was set up for them
            return False
        how = self.model.refresh(design, changed)
        if how is None:
            return False
        if how == "new matrix":
            self.solver.new_matrix()
        self.solver.forget()
        self.timings = {"mesh": 0.0, "compile": time.perf_counter() - t0}
        return True

    def _carry_over(self, X_old: np.ndarray, u_old: np.ndarray, old_model) -> None:
        """Start from the old displacement: interpolated where the new nodes lie in the old mesh, else nearest."""
        from scipy.spatial import cKDTree

        from .mesh.points import interpolation_matrix, locate_cells
        model = self.model
        X = model.V.tabulate_dof_coordinates()[:, :model.dim]
        u = np.empty((len(X), model.bs))
        tree = None
        for lo in range(0, len(X), CARRY_CHUNK):    # in chunks: the search's scratch stays small
            Xc, uc = X[lo:lo + CARRY_CHUNK], u[lo:lo + CARRY_CHUNK]
            cells = locate_cells(old_model.mesh, Xc)
            inside = cells >= 0
            if inside.any():
                S = interpolation_matrix(old_model.V, Xc[inside], cells[inside])
                uc[inside] = (S @ old_model.u.x.array).reshape(-1, model.bs)
            if (~inside).any():
                tree = cKDTree(X_old) if tree is None else tree
                uc[~inside] = u_old[tree.query(Xc[~inside])[1]]
        model.u.x.array[:] = u.ravel()
        model.set_factor(1.0)
        model.carry_over(model.u.vector)
        model.apply_bcs(model.u.vector)
        model.untangle(model.u.vector)

    # -- solving -----------------------------------------------------------------------------------
    @_exclusive
    def solve(self, steps: int | None = None, estimate: bool = False) -> Result:
        """Static equilibrium; warm-started from the last one after the first solve.

        ``estimate``: also estimate the error of every observable (skelfem.estimate: the same
        equilibrium one degree richer on the same mesh); the result's ``errors`` and ``estimate``.

        A warm start that fails (after an edit: a carried-over state that inverts elements, a change the
        parameter path cannot follow) is followed by one solve from rest (not when it found an object not
        held: that is the answer on the path the edits took), the load ramped as
        ``skelfem simulate`` does; the result then says so (``retried_from_rest``: the warm attempt's
        status, and a warning: the load path starts again, which friction's answer can depend on).
        An object that jumps within a load step (skelfem.fem.jumps) is listed in ``events``.
        """
        t0 = time.perf_counter()
        steps = steps or self.design.solver.steps
        log.info("%s: %d DOFs, %d cells", self.design.name, self.dofs,
                 self.model.mesh.topology.index_map(self.model.mesh.topology.dim).size_global)
        warm = self.solved
        report, events = self._equilibrium(steps)
        retried = None
        # a preview goes on from its state; "not held" is physics' answer on this path, not a bad start: a ramp
        # from rest would load grip and weight together (another path) and double the cost of every lost grasp
        if (warm and not report.converged and report.status != BUDGET_SPENT
                and Status.of(report.status) != Status.NOT_HELD):
            retried = report
            log.info("%s: the solve from the last state failed (%s); solving from rest", self.design.name,
                     report.status)
            self.solved = False
            report, events = self._equilibrium(steps)
        return self._result(report, t0, retried, events, estimate)

    def _equilibrium(self, steps: int, stage_steps: int | None = None):
        """(SolveReport, jump events) of one static solve: the load ramped from rest in `steps` steps, or
        a warm re-solve from the last equilibrium (in stage_steps equal steps along the parameter path
        when given)."""
        from .fem.jumps import JumpWatch
        warm = self.solved
        if not warm:                                          # cold: ramp the load from rest
            self.model.to_rest()
        watch = JumpWatch(self.model)
        self.model.step_watchers.append(watch)
        try:
            if not warm:
                report = self.solver.solve(steps)
            elif stage_steps is not None and stage_steps > 1 and self.model.changes:
                report = self.solver.path(dict(self.model.changes), stage_steps)
            else:
                report = self.solver.resolve(steps)
        finally:
            self.model.step_watchers.remove(watch)
        return report, watch.events

    def _result(self, report, t0: float, retried=None, events=(), estimate: bool = False) -> Result:
        """The Result of a static solve that ended with report (result.json's keys, warnings, events; the
        error estimate of every observable if asked and converged)."""
        from .fem.jumps import describe
        self.solved = bool(report.converged) or report.status == BUDGET_SPENT   # a start for the next solve
        timings = dict(self.timings, solve=time.perf_counter() - t0)
        timings["total"] = sum(timings.values())
        self.timings = {"mesh": 0.0, "compile": 0.0}          # paid once per mesh
        data = result_dict(self.design, self.model, report, timings)
        from .terms.capabilities import History
        warnings = list(dict.fromkeys(note for term in self.model.terms if isinstance(term, History)
                                      for note in term.take_notes()))
        if retried is not None:
            data["retried_from_rest"] = {"warm_status": retried.status,
                                         "warm_newton_iterations": int(retried.newton_iterations)}
            warnings.append(f"the solve from the last state failed ({retried.status}); solved again from rest "
                            "(the load path started again)")
        if events:
            data["events"] = _plain(list(events))
            warnings.append(f"a jump within a load step: {describe(events)}; the static answer is one of several "
                            "(try more load steps, or a run in time with [dynamics])")
        if warnings:                         # e.g. friction switched on at a loaded state
            for note in warnings:
                log.warning("%s: %s", self.design.name, note)
            data["warnings"] = warnings
        if estimate and self.solved:
            data.update(self._estimate())
        return Result(data, report, self._state())

    @_exclusive
    def estimate(self) -> dict:
        """The error estimate of every observable at the converged state (skelfem.estimate):
        result.json's ``errors`` ({observable: {"error", "discretisation", "algebraic"}}) and ``estimate``
        (how, at what cost). The state is left as it is."""
        return self._estimate()

    def _estimate(self) -> dict:
        from .estimate import estimate
        out = estimate(self)
        return {"errors": _plain(out["errors"]), "estimate": _plain(out["estimate"])}

    @_exclusive
    def run_stages(self, on_stage=None) -> Result:
        """The design's ``[[stages]]`` in order (skelfem.design.stages): each stage's changes set live, then
        a static solve from the last stage's state and friction history (the first from rest).

        on_stage(stage, result): called after each stage (collective under MPI: a snapshot may be taken).
        A stage that fails ends the run. The Result is the last stage's, with ``stages`` (one entry per
        stage run: its name, status, iterations and read-outs), ``failed_stage`` if one failed, the
        iterations and load steps of every stage summed, and every stage's ``events`` (each naming its
        stage). The session's design is then the last stage's.
        """
        stages = self.design.stages
        if not stages:
            raise DesignError(f"{self.design.source}: stages: the design has no [[stages]]")
        self.solved = False                 # the first stage from rest, as skelfem simulate runs it
        t0 = time.perf_counter()
        entries: list = []
        events: list = []
        result: Any = None
        iterations = load_steps = 0
        for stage in stages:
            self.set(stage.changes, design=stage.design)
            ts = time.perf_counter()
            report, seen = self._equilibrium(stage.steps or stage.design.solver.steps, stage.steps)
            for e in seen:
                e["stage"] = stage.name
            result = self._result(report, ts, events=seen)
            data = result.to_dict()
            entries.append({"name": stage.name, **{k: v for k, v in data.items() if k not in STAGE_LEFT_OUT}})
            events += seen
            iterations, load_steps = iterations + result.newton_iterations, load_steps + result.load_steps
            if on_stage is not None:
                on_stage(stage, result)
            if not result.converged:
                log.info("%s: stage %s failed (%s)", self.design.name, stage.name, result.status)
                break
        data = result.to_dict()
        data.update(stages=entries, newton_iterations=iterations, load_steps=load_steps)
        data["timings"]["total"] = round(time.perf_counter() - t0, 4)
        if events:
            data["events"] = _plain(events)
        if not result.converged:
            data["failed_stage"] = entries[-1]["name"]
        return Result(data, result.report, self._state())

    @_exclusive
    def run_in_time(self, on_step=None, progress=None) -> Result:
        """A run in time ([dynamics]): from rest, steps of dt to the duration (see skelfem.fem.dynamics).

        The Result holds result.json's keys (the final state's read-outs, and a
        ``dynamics`` block with the energy history); ``result.report.trajectory``
        has one row per accepted step (trajectory.csv).
        """
        from .fem.dynamics import Dynamics, dynamics_summary
        if self.design.dynamics is None:
            raise DesignError(f"{self.design.source}: dynamics: missing (a run in time needs a [dynamics] section)")
        t0 = time.perf_counter()
        log.info("%s: %d DOFs, %s, dt %g s to %g s", self.design.name, self.dofs, self.design.dynamics.integrator,
                 self.design.dynamics.dt, self.design.dynamics.duration)
        report = Dynamics(self.model, self.solver, self.design).run(on_step, progress)
        self.solved = False                                   # a moving state, not an equilibrium
        timings = dict(self.timings, solve=time.perf_counter() - t0)
        timings["total"] = sum(timings.values())
        self.timings = {"mesh": 0.0, "compile": 0.0}
        data = result_dict(self.design, self.model, report, timings)
        data["dynamics"] = _plain(dynamics_summary(self.design, report))
        return Result(data, report, self._state())

    def _state(self):
        """(X, u, cells) of the mesh's vertices now, copied, for Result.displacement (serial only)."""
        if self.comm.size > 1:
            return None
        from .io.xdmf import vertex_displacements
        X, u, cells = vertex_displacements(self.model)
        return X.copy(), u.copy(), cells.copy()

    # -- clean-up ------------------------------------------------------------------------------------
    def close(self) -> None:
        """Free the solver (PETSc objects); the session can do nothing more. Closing twice is fine."""
        if not self._lock.acquire(blocking=False):
            raise SessionError(f"{self.design.name}: this Session is busy in another thread")
        try:
            if self.solver is not None:
                self.solver.destroy()
                self.solver = None
                self._release(self.model)
            self._closed = True
        finally:
            self._lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

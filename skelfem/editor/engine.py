"""The editor's solver side: one Session driven by whole designs (dicts of the TOML's keys).

``Engine.solve(design)`` validates the design, compares it with the one the
Session holds and takes the cheapest way there:

* nothing changed: the last answer again (no solve);
* only live parameters changed (contractions, pretensions, stiffnesses, E and nu,
  loads, pin moves, ...; ``model.parameters()``): ``Session.set``, a warm re-solve
  on the same mesh and matrix;
* anything else (outlines, holes, cable sketches, markers, mesh size, ...):
  ``Session.edit``, with the last solution carried over: a re-mesh, or the
  same mesh when the outlines and the mesh size did not change (cables,
  markers, pins...).

``draft=True`` (the page sends it while a vertex is being dragged) keeps the
mesh and moves its nodes with the dragged outline (``Session.edit(...,
morph=True)``, :mod:`skelfem.mesh.morph`): no meshing, no new DOF numbering, no
form compiled (``Model.refresh``: only the cables, markers and other
hand-written terms are built again), the last equilibrium as the start. Where the moved mesh would be poor it
re-meshes. The page sends the same design without ``draft`` on release,
which re-meshes, so the answer is the one ``skelfem simulate`` gives. In 3D a
draft that moves or turns bones (their ``move`` and ``rotate``) moves the nodes
the same way (:mod:`skelfem.mesh.morph3d`), and its frames take modified Newton
steps with the factorisation the last solve left instead of factorising again
(:mod:`.frames3d`). Such a draft (the bones' poses its only change) is not
checked by OpenCASCADE (parse_design's ``poses_of``): the moved mesh checks it
(its tetrahedra keep their orientation, so the bones stay inside the body and
apart); where the mesh cannot follow, the draft is parsed and checked exactly
(a bone out of the body: the 422 at its key) and re-meshed, and the release
is always checked exactly. ``Engine.ik`` runs Soft IK
(skelfem.analysis.control.SoftIK, the
same as ``skelfem ik``) for a marker target from the current equilibrium;
ligaments are never actuated.

A draft has a frame budget (``frame_budget``, FRAME_SECONDS): Newton stops
after the first step that ends past it, on models without path dependence
(LoadStepper.deadline), and the answer is that state, ``converged`` false,
status ``frame_budget``, with its mesh. The same design asked again goes on
from there ("go on"); the next design starts from it (``set`` with the tangent
predictor, or moved nodes). A request without ``draft`` is solved to the
end, unless it asks for frames (``framed``: the page's release of a drag: the new
mesh, then Newton within the same budget, and the page asks again until it is
converged).

What goes back: the mesh's cells, regions and rest nodes only when the
client does not hold them already (``have``: the ``topology`` key of the
last mesh it got; the same mesh with moved nodes keeps its key), and the
per-cell fields only when asked (``fields``): a frame of a drag then carries
the deformed nodes, cables, markers and objects only.

Every answer carries a ``certificate``: the residual |R| of the state shown,
the tolerance a batch solve (``skelfem simulate``) of the design holds its
answer to (at least: :func:`skelfem.fem.certificate.certificate`), their
ratio, and ``state``: "converged" only for a state on the design's own mesh
(not a draft's moved nodes) with |R| at or below that tolerance, else
"preview" and ``why``.

A bad design raises EditError with the one-line DesignError message and its
key (e.g. ``bones.proximal.outline``) and leaves the Session as it was, so the
last valid result stays the current one. Not thread-safe: one thread (the
worker's) calls it.
"""
from __future__ import annotations

import copy
import json
import logging
import math
import re
import time
import weakref

import numpy as np

from ..design.spec import DesignError
from ..design.parse import changed_keys, flatten, parse_design
from .payload import mesh_payload

log = logging.getLogger("skelfem")

# A draft's Newton steps (a handle being dragged, draft=True) stop after the first one that ends this long after
# the request began (at least one step): the frame is sent as a "preview", and the page asks for the same design
# again, which goes on from that state. Engine(frame_budget=None) solves every draft to the end.
FRAME_SECONDS = 0.006
IK_LIVE_SOLVES = 12       # forward solves of one Soft IK request while a target is dragged
IK_FINAL_SOLVES = 40      # ... and when it is let go (as `skelfem ik`)
CONTRACTION_DECIMALS = 4  # contractions Soft IK finds are written back rounded to 0.1 um
TOP_KEYS = ("format", "name", "dim", "thickness", "mesh", "materials", "body", "bodies", "bones", "cables", "pins",
            "loads", "grounds", "contact", "markers", "solver", "gravity", "tractions", "fabrication", "objects",
            "dynamics")
POSE_KEY = re.compile(r"bones\.[^.]+\.(move|rotate(\.[a-z]+)?)")     # flat keys of a 3D bone's pose


# The interactive budget: a design whose mesh is estimated (skelfem.design.resources) beyond this many
# unknowns is refused (422, key mesh.size) instead of keeping the solver busy for minutes with no way
# to cancel; about 1 s a solve on 2 cores (finger.toml at mesh.size 2 has 2,300). `skelfem edit --max-dofs`.
MAX_DOFS = {2: 60_000, 3: 30_000}


def budget(max_dofs=None) -> dict:
    """{dim: DOF limit}: MAX_DOFS, or one number for both dimensions, or a dict of some."""
    if isinstance(max_dofs, (int, float)) and not isinstance(max_dofs, bool):
        max_dofs = {2: int(max_dofs), 3: int(max_dofs)}
    return {**MAX_DOFS, **(max_dofs or {})}


def check_budget(d, limits: dict) -> None:
    """EditError 422 (key mesh.size) for a design estimated beyond the interactive budget."""
    from ..design.resources import estimate
    dofs, limit = estimate(d)["dofs"], limits[d.dim]
    if not dofs <= limit:
        shown = f"{dofs:,.0f}" if math.isfinite(dofs) and dofs < 1e12 else f"{dofs:.3g}"
        raise EditError(f"{d.source}: mesh.size: {d.mesh.size:g} mm gives about {shown} unknowns at "
                        f"P{d.mesh.degree}, more than the editor solves interactively ({limit:,} in "
                        f"{d.dim}D; skelfem edit --max-dofs); use a larger mesh.size, or skelfem simulate",
                        "mesh.size", 422)


class EditError(Exception):
    """A request the engine cannot carry out; ``key`` names the design element at fault ("" if none)."""

    def __init__(self, message: str, key: str = "", status: int = 422):
        super().__init__(message)
        self.message, self.key, self.status = message, key, status

    def to_dict(self) -> dict:
        return {"error": self.message, "key": self.key}


def error_key(message: str, source: str) -> str:
    """The design key of a one-line DesignError (``source: key: message``), or ""."""
    rest = message[len(source) + 2:] if message.startswith(f"{source}: ") else message
    if rest.startswith("--set "):
        return ""
    key = rest.split(": ", 1)[0] if ": " in rest else ""
    top = re.split(r"[.\[]", key, maxsplit=1)[0]
    return key if top in TOP_KEYS else ""


def live_changes(old: dict, new: dict, live) -> dict | None:
    """{key: value} taking flat design old to new if only live parameters differ; None if not."""
    changed = changed_keys(old, new)
    if any(k not in new or k not in live for k in changed):
        return None
    return {k: new[k] for k in changed}


class Engine:
    """A Session that follows the designs it is given; answers are payload dicts (see solve)."""

    def __init__(self, design: dict, source: str, comm=None, max_dofs: dict | int | None = None,
                 frame_budget: float | None = FRAME_SECONDS):
        from mpi4py import MPI

        from ..session import Session
        self.source = source
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.max_dofs = budget(max_dofs)
        d = self.parse(design)
        self.session = Session(d, comm=self.comm)
        self.flat, self.draft, self.answer, self.good = flatten(d.raw), False, None, d
        self.frame_budget = frame_budget
        self.preview = False                  # the state is a draft frame stopped at its budget (not converged)
        self.preview_steps = 0                # Newton steps of the frames since the last converged state
        self.initial = d                      # recovery's last resort: the design the editor started with
        self._parsed: tuple | None = None   # (the JSON of the last design parsed, its Design, whether checked fully)
        self._mesh_seen, self._meshes = None, 0          # the mesh the topology key names, and how many so far
        from .frames3d import StaleFrames
        self.frames3d = StaleFrames()                    # a 3D drag's frames: the held factorisation reused
        self._rest_tol: tuple = (None, None, 0.0)        # (Design, fem.certificate.rest_key, its tolerance)
        self.first = self._answer(self.session.solve(), time.perf_counter(), "built")

    # -- designs ----------------------------------------------------------------------------------
    def parse(self, design, budget: bool = True, poses_of=None):
        """A validated Design from a dict (within the interactive budget); EditError (422) naming the key otherwise.
        poses_of: parse_design's (the solids' check of that Design kept)."""
        if not isinstance(design, dict):
            raise EditError("the design must be a JSON object of the TOML's keys", "", 400)
        try:
            d = parse_design(design, self.source, poses_of=poses_of)
        except DesignError as exc:
            raise EditError(str(exc), error_key(str(exc), self.source)) from None
        except RecursionError:
            raise EditError(f"{self.source}: the design is nested too deeply", "", 400) from None
        if budget:
            self.check_budget(d)
        return d

    def check_budget(self, d) -> None:
        check_budget(d, self.max_dofs)

    def _parse_again(self, design, poses_of=None):
        """parse(design), or the Design of the last call when design is the same (a frame asked again);
        poses_of: see parse_design (a Design parsed with it is not reused for a request without)."""
        try:
            key = json.dumps(design, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError):
            return self.parse(design)
        if self._parsed is not None and self._parsed[0] == key and (self._parsed[2] or poses_of is not None):
            return self._parsed[1]
        d = self.parse(design, poses_of=poses_of)
        self._parsed = (key, d, poses_of is None)
        return d

    def _poses_only(self, design) -> bool:
        """Whether design (a dict) differs from the Session's 3D design in its bones' poses only (a bone
        dragged or turned): a draft of it is checked by the moved mesh, not by OpenCASCADE (see solve)."""
        if self.session is None or self.flat is None or self.session.design.dim != 3 or not isinstance(design, dict):
            return False
        try:
            changed = changed_keys(self.flat, flatten(design))
        except (TypeError, ValueError, RecursionError):
            return False
        return bool(changed) and all(POSE_KEY.fullmatch(k) for k in changed)

    def topology(self) -> str:
        """A key of the mesh's cells and regions: the same while the mesh is (its nodes may move), new after
        a re-mesh."""
        mesh = self.session.model.mesh
        if self._mesh_seen is None or self._mesh_seen() is not mesh:
            self._mesh_seen, self._meshes = weakref.ref(mesh), self._meshes + 1
        return f"mesh-{self._meshes}"

    def _mesh(self, have: str | None, fields: bool) -> dict:
        """The mesh payload of the state: topology left out if the client has it, fields only if asked."""
        key = self.topology()
        mesh = mesh_payload(self.session.model, topology=have != key, fields=fields)
        mesh["topology"] = key
        return mesh

    @staticmethod
    def _fits(mesh: dict | None, have: str | None, fields: bool) -> bool:
        """Whether a mesh payload made before holds what a client with topology ``have`` asks for."""
        return mesh is not None and ("cells" in mesh or have == mesh.get("topology")) and \
            ("fields" in mesh or not fields or mesh.get("dim") != 2)

    @property
    def design(self):
        return self.session.design if self.session is not None else self.good

    def ensure(self) -> None:
        """A Session to work on: after a recovery that failed, try again (EditError 503 if it cannot)."""
        if self.session is None:
            self.recover()

    def _answer(self, result, t0: float, how: str, have: str | None = None, fields: bool = True) -> dict:
        from ..fem.report import BUDGET_SPENT
        self.preview = result.status == BUDGET_SPENT
        self.preview_steps = self.preview_steps + result.newton_iterations if self.preview else 0
        payload = result.to_dict()
        payload["mesh"] = self._mesh(have, fields) if result.converged or self.preview else None
        payload["certificate"] = self.certificate(result.converged)
        payload["editor"] = {"how": how, "draft": self.draft, "mesh_size": float(self.session.design.mesh.size),
                             "seconds": round(time.perf_counter() - t0, 4)}
        self.frames3d.note(self.session, result)
        if result.converged:
            self.answer, self.good = payload, self.session.design
            if not self.draft:
                self.session.prepare_moves()        # 3D: the next drag's first frame starts at once
        return payload

    def certificate(self, converged: bool) -> dict:
        """What the shown state is worth: its residual against the batch tolerance (see the module doc)."""
        from ..fem.certificate import certificate, rest_key
        solver, steps = self.session.solver, self.session.design.solver.steps
        # frames of one design share the tolerance (one assembly less): the same Design object (a set, an edit or
        # a recovery makes a new one; the cache holds it, so its id is not reused) and the same rest_key
        design, key = self.session.design, rest_key(solver, steps)
        held, held_key, held_tol = self._rest_tol
        residual, tol = certificate(solver, steps, held_tol if key is not None and held is design and
                                    held_key == key else None)
        self._rest_tol = (design, key, tol)
        ratio = residual / tol if tol > 0 else math.inf
        if self.preview:
            why = "the frame's time was spent; the solve goes on"
        elif not converged:
            why = "the solve did not converge"
        elif not ratio <= 1.0:
            why = "the residual is above the batch tolerance"
        elif self.draft:
            why = "moved mesh nodes: a new mesh follows on release"
        else:
            why = ""
        finite = math.isfinite(ratio)
        return {"state": "preview" if why else "converged", "why": why,
                "residual": residual if finite else None, "tolerance": tol, "ratio": ratio if finite else None}

    # -- solving --------------------------------------------------------------------------------------
    def solve(self, design: dict, draft: bool = False, framed: bool = False, have: str | None = None,
              fields: bool = True) -> dict:
        """Equilibrium of design (a dict): result.json's keys plus ``mesh`` and ``editor`` (how it was got).

        ``converged`` false: the solve failed; ``mesh`` is None and the last valid answer stays.
        draft: a handle is being dragged (moved nodes, a frame budget); framed: a frame budget for a request
        that is not a draft (a release); have, fields: what the mesh payload leaves out (see the module doc).
        """
        t0 = time.perf_counter()
        start = time.monotonic()
        draft = bool(draft)
        loose = draft and self._poses_only(design)       # the bones' new places: checked by the moved mesh
        d = self._parse_again(design, self.session.design if loose else None)
        self.ensure()
        flat = flatten(d.raw)
        kept = draft or not self.draft              # a request not a draft re-meshes moved nodes (a release)
        if flat == self.flat and kept and self.session.solved:
            if not self.preview and self.answer is not None:
                mesh = self.answer["mesh"]
                mesh = mesh if self._fits(mesh, have, fields) else self._mesh(have, fields)
                return dict(self.answer, mesh=mesh, editor=dict(self.answer["editor"], how="unchanged",
                                                                seconds=round(time.perf_counter() - t0, 4)))
            how = "go on"                           # from the last frame's state
        else:
            self.preview_steps = 0                  # the iteration limit counts the frames of one design
            changes = live_changes(self.flat, flat, self.session.model.parameters()) if kept else None
            if changes is not None:
                how = "set"
                self.session.set(changes, design=d)       # validated above
            else:
                moved = self._edit(d, draft, moved_only=loose)
                if moved == "not moved":                 # the mesh cannot follow: the exact check, then re-mesh
                    d = self._parse_again(design)
                    moved = self._edit(d, draft)
                how = f"edit ({moved})"
                self.draft = draft
            self.flat = flat
        solver = self.session.solver
        if draft and d.dim == 3 and self.frame_budget is not None and self.preview_steps < solver.max_iterations:
            # 3D: no new factorisation; a new pose whose step would outlast the frame: the moved state
            frame = self.frames3d.frame(self.session, start + self.frame_budget, new=how != "go on")
            if frame is not None and (frame.newton_iterations or frame.predictor):
                return self._answer(frame, t0, how, have, fields)
        # frames of one design go on until converged, or failed: past the solver's own iteration limit the
        # next is solved to the end (a Newton that never converges is not asked again for ever)
        budget = (draft or framed) and self.frame_budget is not None and self.preview_steps < solver.max_iterations
        if budget and how == "edit (re-meshed)" and self.session.solved and not self.session.model.path_dependent \
                and time.monotonic() >= start + self.frame_budget:
            # a release's new mesh took the frame's time: its first frame is the state carried over onto it,
            # and Newton starts with the page's next ask
            from .frames3d import Frame
            return self._answer(Frame(self.session, 0, time.perf_counter() - t0), t0, how, have, fields)
        solver.stepper.deadline = start + self.frame_budget if budget else None
        try:
            result = self.session.solve()
        finally:
            solver.stepper.deadline = None
        return self._answer(result, t0, how, have, fields)

    def _edit(self, d, draft: bool, moved_only: bool = False) -> str:
        """Session.edit (moving the mesh's nodes for a draft); returns how the mesh was got."""
        from ..mesh.geometry import MeshingError
        old = self.session.design
        try:
            return self.session.edit(d, morph=draft, preview=draft, moved_only=moved_only)
        except (DesignError, MeshingError) as exc:   # the old mesh, model and solution are intact
            self.session.design = old
            raise EditError(f"{self.source}: {exc}" if isinstance(exc, MeshingError) else str(exc),
                            error_key(str(exc), self.source)) from None

    def ik(self, design: dict, marker: str, target, final: bool = True) -> dict:
        """Soft IK: tendon contractions that bring marker to target, from the current equilibrium.

        Returns solve()'s answer for the design with those contractions (rounded to
        0.1 um, re-solved warm), plus ``new_design`` (the design with them) and ``ik``: target,
        position, error, tol, reached, status, forward solves.
        """
        from ..analysis.control import SoftIK
        t0 = time.perf_counter()
        if not isinstance(marker, str):
            raise EditError("marker: must be a marker name", "markers", 400)
        answer = self.solve(design)
        if not answer["converged"]:
            raise EditError(f"{self.source}: the design's own equilibrium failed ({answer['status']}); "
                            "no Soft IK from there", "", 422)
        d = self.session.design
        if marker not in d.markers:
            raise EditError(f"{self.source}: markers.{marker}: no such marker (have: "
                            f"{', '.join(d.markers) or 'none'})", "markers", 422)
        if not d.tendons:
            raise EditError(f"{self.source}: cables: Soft IK needs a tendon to steer the marker", "cables", 422)
        target = _point(target, d.dim)
        ik = SoftIK(self.session, marker, max_solves=IK_FINAL_SOLVES if final else IK_LIVE_SOLVES)
        res = ik.solve(target)
        changes = {f"cables.{n}.contraction": round(float(u), CONTRACTION_DECIMALS)
                   for n, u in zip(ik.names, res.contractions)}
        self.session.set(changes)
        self.flat = flatten(self.session.design.raw)
        answer = self._answer(self.session.solve(), t0, "ik")
        if not answer["converged"]:
            return answer
        position = np.asarray(answer["markers"][marker]["position"], dtype=float)
        error = float(np.linalg.norm(position - target))
        answer["new_design"] = copy.deepcopy(self.session.design.raw)
        answer["ik"] = {"marker": marker, "target": target.tolist(), "position": position.tolist(),
                        "error": error, "tol": float(ik.tol), "reached": bool(error < ik.tol),
                        "status": "reached" if error < ik.tol else res.status,
                        "forward_solves": int(res.forward_solves), "contractions": changes}
        return answer

    def recover(self) -> None:
        """After an unexpected failure: a fresh Session on the last design that solved.

        Never the design that was being solved when it failed (only converged
        designs become ``good``). If that fails too, the design the editor
        started with; if that fails, no Session: the next request tries again,
        and a request is answered 503 while none can be had, never 500 for ever.
        """
        from ..session import Session
        old, self.session = self.session, None
        self.draft, self.answer, self.flat, self.preview, self.preview_steps = False, None, None, False, 0
        if old is not None:
            try:
                old.close()
            except Exception:  # noqa: BLE001 - the old session is dropped either way
                pass
        failures = []
        for d in dict.fromkeys((self.good, self.initial)):
            session = None
            try:
                session = Session(d, comm=self.comm)
                result = session.solve()
            except Exception as exc:  # noqa: BLE001 - the next candidate
                failures.append(f"{type(exc).__name__}: {exc}"[:200])
                if session is not None:
                    try:
                        session.close()
                    except Exception:  # noqa: BLE001
                        pass
                self.good = self.initial          # never rebuilt again
                continue
            self.session, self.flat = session, flatten(d.raw)
            self._answer(result, time.perf_counter(), "recovered")
            return
        raise EditError(f"{self.source}: the solver could not start again ({'; '.join(failures)})", "", 503)

    def close(self) -> None:
        if self.session is not None:
            self.session.close()


def _point(value, dim: int) -> np.ndarray:
    if (not isinstance(value, (list, tuple)) or len(value) != dim
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       and abs(v) <= 1e7 for v in value)):
        raise EditError(f"target: must be {dim} finite numbers (mm)", "target", 400)
    return np.asarray(value, dtype=float)

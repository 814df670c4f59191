"""The validated design: frozen dataclasses, the limits every value is held to, and DesignError
(raised with the file and the key; see skelfem.design.parse).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from . import polygons
from .objects import FrictionSpec



FORMAT = 1
MAX_COORDINATE = 1e7      # mm: geometry beyond +-10 km is a typo, and overflows the predicates
MAX_STEPS = 10_000        # load steps and Newton iterations: a cap against runaway runs
MAX_NAME = 100            # bytes in a design, entry or marker name
LINE_SEARCHES = ("auto", "energy", "curved", "residual", "none", "trust_region")
ENERGY_LINE_SEARCHES = ("energy", "curved")   # line searches on Pi: the only ones rigid bones and self-contact allow
INTEGRATORS = ("euler", "bdf2")
MAX_TIME_STEPS = 1_000_000   # duration / dt: a cap against runaway runs
# every [[...]] array of tables of the design contract: its entries are named, --set and flattened by name
SECTIONS_BY_NAME = ("bodies", "bones", "cables", "pins", "loads", "grounds", "tractions", "objects", "stages")
PRIMITIVES = ("box", "cylinder", "sphere", "extrude")
LINEAR_SOLVERS = ("auto", "direct", "iterative")


class DesignError(ValueError):
    """A design that cannot be simulated; the message is one line for the user."""


# -- the validated design --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Material:
    name: str
    E: float          # Young's modulus, MPa
    nu: float         # Poisson's ratio
    density: float | None = None   # kg/m^3 (gravity, dynamics); None: not given


@dataclass(frozen=True, eq=False)
class MeshSpec:
    size: float = 2.0     # target edge length, mm
    degree: int = 1       # Lagrange degree of u


@dataclass(frozen=True, eq=False)
class Body:
    material: str
    outline: np.ndarray | None = None        # 2D: (n, 2)
    holes: tuple = ()                        # 2D: tuple of (m, 2)
    solids: tuple = ()                       # 3D: tuple of primitive dicts
    name: str = "body"                       # [[bodies]]: the entry's name; [body]: "body"


@dataclass(frozen=True, eq=False)
class Bone:
    name: str
    material: str
    outline: np.ndarray | None = None
    solids: tuple = ()
    rigid: bool = False   # a rigid body: its nodes follow 3 (2D) / 6 (3D) rigid DOFs, its cells carry no energy
    pose: dict | None = None   # 3D: move and rotate of its solids (skelfem.design.pose), None if none


@dataclass(frozen=True, eq=False)
class CableSpec:
    name: str
    kind: str             # "tendon" or "ligament"
    path: np.ndarray      # (n, dim) sketch polyline
    stiffness: float      # k, N/mm
    contraction: float = 0.0   # tendon: u, mm
    pretension: float = 0.0    # ligament: rest-length shortening, mm
    anchor_radius: float | None = None   # mm; an end in silicone pulls on a disk/ball this wide (None: default)
    schedule: np.ndarray | None = None   # tendons, dynamics: (n, 2) rows [t (s), contraction (mm)], t increasing
    friction: float = 0.0      # mu: Coulomb friction against its channel at every via point and bend
    friction_by_material: tuple = ()   # ((material, mu), ...) instead: mu by the material around the via point

    def contraction_at(self, t: float) -> float:
        """The contraction at time t: the schedule, piecewise linear and held beyond its ends, or the
        constant contraction if there is no schedule."""
        if self.schedule is None:
            return self.contraction
        return float(np.interp(t, self.schedule[:, 0], self.schedule[:, 1]))


@dataclass(frozen=True, eq=False)
class PinSpec:
    name: str
    region: np.ndarray    # (2, dim): [min, max]
    kind: str = "fixed"   # "fixed" (Dirichlet) or "spring" (penalty)
    stiffness: float = 0.0
    move: np.ndarray | None = None
    angle: float = 0.0                   # rotate.angle: the pinned boundary turned by this many degrees ...
    centre: np.ndarray | None = None     # ... about this point (rotate.centre; required with an angle) ...
    axis: np.ndarray | None = None       # ... and, in 3D, this unit axis (rotate.axis)


@dataclass(frozen=True, eq=False)
class LoadSpec:
    name: str
    at: np.ndarray
    force: np.ndarray


@dataclass(frozen=True, eq=False)
class TractionSpec:
    name: str
    region: np.ndarray    # (2, dim): [min, max]; the boundary inside it is loaded
    traction: np.ndarray  # MPa: a dead load per area of reference boundary


@dataclass(frozen=True, eq=False)
class GroundSpec:
    name: str
    point: np.ndarray
    normal: np.ndarray    # unit normal, pointing to the side the body stays on
    stiffness: float


@dataclass(frozen=True, eq=False)
class ContactSpec:
    self_contact: bool = False
    dhat: float = 0.3


@dataclass(frozen=True, eq=False)
class SolverSpec:
    steps: int = 1
    max_iterations: int = 50
    line_search: str = "auto"
    rtol: float = 1e-9
    atol: float | None = None     # N, absolute, when given; None: ATOL_RELATIVE x the design's force scale
    linear: str = "auto"          # Newton's linear solves: "direct" (MUMPS), "iterative" (Krylov + AMG), "auto"


ATOL_RELATIVE = 1e-12     # the default |R| that ends Newton, relative to force_scale (1e-10 N on finger.toml)


def force_scale(design) -> float:
    """N: the body's modulus times its cross-section (2D: sqrt(area) x thickness; 3D: volume^(2/3)).

    A residual tolerance in newtons is meaningless across unit scales: the old
    absolute 1e-10 N let a 1 um body "converge" at its start, 17 % off.
    """
    E = max(float(design.materials[b.material].E) for b in design.bodies)
    measure = max(float(design.measure or 0.0), 0.0)
    if design.dim == 2:
        area = math.sqrt(measure) * float(design.thickness)
    else:
        area = measure ** (2.0 / 3.0)
    scale = E * area
    return scale if math.isfinite(scale) and scale > 0 else 1.0


@dataclass(frozen=True, eq=False)
class DynamicsSpec:
    """The [dynamics] section: its presence makes a run dynamic."""
    dt: float                         # time step, s
    duration: float                   # s
    integrator: str = "bdf2"          # "euler" or "bdf2"
    damping_mass: float = 0.0         # Rayleigh a, 1/s: damping force a M v
    damping_stiffness: float = 0.0    # Rayleigh b, s: damping force b K v (K: elastic tangent at the last step)

    @property
    def steps(self) -> int:
        """Number of time steps of size dt (the last one may be shorter)."""
        return int(math.ceil(self.duration / self.dt * (1.0 - 1e-12)))


@dataclass(frozen=True, eq=False)
class FabricationSpec:
    """The [fabrication] section (skelfem fabricate), every default resolved; lengths in mm."""
    channel_diameter: float = 1.2     # tendon channels through the bones
    anchor_diameter: float = 1.5      # ligament anchor holes (the rubber band loops through)
    bone_depth: float = 0.0           # 2D: extrusion depth of the bones, centred in the slab
    min_wall: float = 0.4             # least printed material left around a channel, hole or socket
    wall: float = 5.0                 # mould wall beyond the body
    clearance: float = 0.2            # fit of registration pins and bone pegs in their holes
    pour_diameter: float = 6.0
    vent_diameter: float = 2.0
    vents: int = 2
    peg_diameter: float = 2.0         # pegs that hold the bones in the mould
    socket_depth: float = 2.0         # sockets in the bones that the pegs enter (half as deep where no room)
    post_diameter: float = 2.0        # guide posts holding a cable's bends in silicone while it is cast
    route_tolerance: float = 0.3      # how far the cast cable may lie from its sketch
    split_point: np.ndarray | None = None    # the mould's parting plane (2D: the slab's mid-plane; 3D: None
                                             # lets skelfem fabricate choose the fewest undercuts)
    split_normal: np.ndarray | None = None


class FrozenDict(dict):
    """A dict that refuses every change (TypeError), and pickles (MPI sends designs between ranks)."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a Design's data is read-only: change a copy (Design.raw) and parse it again")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = __ior__ = _refuse

    def __reduce__(self):
        return (FrozenDict, (dict(self),))


def freeze(value):
    """A read-only deep copy of TOML-like data: dicts as FrozenDict, lists as tuples."""
    if isinstance(value, Mapping):
        return FrozenDict({k: freeze(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(freeze(v) for v in value)
    if isinstance(value, np.ndarray):
        return tuple(freeze(v) for v in value.tolist())
    return value


def thaw(value):
    """A plain mutable deep copy of frozen data: dicts and lists again."""
    if isinstance(value, Mapping):
        return {k: thaw(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [thaw(v) for v in value]
    return value


@dataclass(frozen=True, eq=False)
class Design:
    source: str
    name: str
    dim: int
    thickness: float
    mesh: MeshSpec
    materials: dict
    body: Body                # the first of bodies (the only one of a [body] design)
    bones: tuple
    cables: tuple
    pins: tuple
    loads: tuple = ()
    grounds: tuple = ()
    contact: ContactSpec = field(default_factory=ContactSpec)
    markers: dict = field(default_factory=dict)
    solver: SolverSpec = field(default_factory=SolverSpec)
    gravity: np.ndarray | None = None    # m/s^2 as written; None: no gravity
    tractions: tuple = ()
    fabrication: FabricationSpec = field(default_factory=FabricationSpec)
    dynamics: DynamicsSpec | None = None   # None: a static run
    friction: FrictionSpec = field(default_factory=FrictionSpec)   # Coulomb coefficients (design.objects)
    objects: tuple = ()                    # ObjectSpec: free rigid bodies (design.objects)
    bodies: tuple = ()                     # Body: every soft body ([[bodies]]), or (body,)
    stages: tuple = ()                     # StageSpec: a static scenario in steps (design.stages)
    format: int = FORMAT
    data: Mapping = field(default_factory=dict)   # the TOML data after overrides, read-only (see raw)
    measure: float = 0.0      # body area (2D, mm^2) or volume (3D, mm^3), bones included
    vertices: int = 0         # polygon vertices of all outlines (2D) / primitives (3D)

    def __post_init__(self):
        object.__setattr__(self, "data", freeze(self.data))
        if not self.bodies:
            object.__setattr__(self, "bodies", (self.body,))

    @property
    def body_loops(self) -> list:
        """2D: every body's outline and holes (the even-odd rule over them is the soft region)."""
        return polygons.loops_of(self.bodies)

    @property
    def raw(self) -> dict:
        """The TOML data after overrides as a fresh dict: edit it and hand it to Session.edit or
        parse_design; changing it never changes this Design (nor a Session that holds it)."""
        return thaw(self.data)

    @property
    def tendons(self) -> tuple:
        return tuple(c for c in self.cables if c.kind == "tendon")

    def cable(self, name: str) -> CableSpec:
        return next(c for c in self.cables if c.name == name)



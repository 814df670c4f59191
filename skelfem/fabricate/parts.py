"""What a fabrication plan holds: frames of the parting plane, the tools cut from the parts, the plan itself."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def cable_points(design, cable) -> np.ndarray:
    """A cable's sketch in 3D: 2D paths lie in the slab's mid-plane z = thickness / 2."""
    p = np.asarray(cable.path, float)
    if design.dim == 2:
        p = np.column_stack([p, np.full(len(p), design.thickness / 2)])
    return p


def where_text(x) -> str:
    """A point for a message: (x, y, z) to three significant digits."""
    return "(" + ", ".join(f"{v:.3g}" for v in x) + ")"


def cable_radius(spec, cable) -> float:
    """The radius of a cable's channel: channel_diameter for tendons, anchor_diameter for ligaments."""
    return (spec.channel_diameter if cable.kind == "tendon" else spec.anchor_diameter) / 2


# -- the plan's data ---------------------------------------------------------------------------------------------
@dataclass
class Frame:
    """The mould's axes: u, v span the parting plane n . x = c; the block spans lo..hi in (u, v, n)."""

    u: np.ndarray
    v: np.ndarray
    n: np.ndarray
    c: float
    lo: np.ndarray = None
    hi: np.ndarray = None

    @classmethod
    def from_normal(cls, point, normal) -> "Frame":
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        k = int(np.argmax(np.abs(n)))
        axis = np.eye(3)[(k + 1) % 3]
        u = axis - (axis @ n) * n
        u /= np.linalg.norm(u)
        return cls(u, np.cross(n, u), n, float(n @ np.asarray(point, float)))

    @property
    def matrix(self) -> np.ndarray:
        """Columns u, v, n: global = matrix @ (u, v, n) coordinates."""
        return np.column_stack([self.u, self.v, self.n])

    def local(self, x) -> np.ndarray:
        return np.asarray(x, float) @ self.matrix

    def world(self, y) -> np.ndarray:
        return np.asarray(y, float) @ self.matrix.T

    def reach(self, point, d) -> float:
        """How far from a point in the block along the unit direction d the block's boundary is."""
        y0, dy = self.local(point), self.local(d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(dy > 0, (self.hi - y0) / dy, np.where(dy < 0, (self.lo - y0) / dy, np.inf))
        return float(t.min())


@dataclass
class Tool:
    """A cylinder-swept cut or addition: an axis polyline, its radius, where it extends past its ends."""

    kind: str              # "channel", "anchor", "sheath", "socket", "peg", "post", "rod", "rod_hole", "pin",
    #                        "pin_hole", "pour", "vent", "exit", "pry", "clamp"
    points: np.ndarray     # (k, 3) axis polyline
    radius: float
    bone: str | None = None
    cable: str | None = None
    extend: tuple = (0.0, 0.0)     # lengths the cylinder runs on beyond the first and the last point
    side: str | None = None        # pegs and posts: the mould half they belong to, "bottom" or "top"; clamps: the bolt

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """The cylinder's end points, each end extended along its segment."""
        p = self.points
        d0 = (p[0] - p[1]) / np.linalg.norm(p[0] - p[1])
        d1 = (p[-1] - p[-2]) / np.linalg.norm(p[-1] - p[-2])
        return p[0] + self.extend[0] * d0, p[-1] + self.extend[1] * d1


@dataclass
class Plan:
    """Everything the build pass needs: tools per part, the frame and block, the reference volumes."""

    design: object
    spec: object
    frame: Frame
    scale: float
    bone_tools: dict = field(default_factory=dict)      # bone name -> [Tool]
    pegs: list = field(default_factory=list)            # Tools of kind "peg"
    mould_tools: list = field(default_factory=list)     # pins, pin holes, pour, vents, exits
    body_volume: float = 0.0
    bone_volumes: dict = field(default_factory=dict)    # un-cut bone volumes (probe pass)
    notes: list = field(default_factory=list)
    body_surface: object = None                         # the probe's triangulated body and bones (Surface)
    bone_surfaces: dict = field(default_factory=dict)
    posts: list = field(default_factory=list)           # Tools of kind "post": cable bends held in silicone
    routes: dict = field(default_factory=dict)          # cable -> how its cast line keeps to the sketch
    flow: dict = field(default_factory=dict)            # pour, high points, vents, air under bones, undercuts



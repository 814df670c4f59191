"""What a solve sends to the page and to API scripts: result.json plus the deformed mesh.

``mesh_payload(model)`` returns, in mm:

* ``x``, ``y``: rest and deformed coordinates of the mesh vertices (P1 geometry; for P2 the
  vertex values), ``cells``: vertex indices per triangle (2D) or per boundary triangle (3D),
  ``regions``: region tag per cell and ``region_names`` (tag -> "body" / "bone:NAME");
* ``fields`` (2D): per cell, ``stretch`` (largest principal stretch of F) and
  ``energy_density`` (the Neo-Hookean psi(F) of skelfem.terms.elasticity, N mm / mm^3);
* ``cables``: per cable its kind, via points at rest and deformed (the sketch cut at every
  mesh facet, as the solver routes it), tension, length, rest length and ``slack``;
* ``markers``: name -> deformed position.

Numbers are rounded to 0.1 um (1e-4 mm): far below what a picture shows, and a third
of the bytes. The coordinates (``x``, ``y``, the cables' ``via`` and ``via_rest``) are numpy
arrays; :func:`json_default` writes them as JSON lists, or, for a client that asks for them
packed (the page, every frame of a drag), as ``{"f32": base64 of little-endian float32,
"shape": [rows, columns]}``: no float is formatted as text (a frame of finger.toml: 19 kB of
JSON and 1-3 ms to write as lists).
"""
from __future__ import annotations

import base64

import numpy as np

DECIMALS = 4


def _round(a) -> list:
    return _rounded(a).tolist()


def _rounded(a) -> np.ndarray:
    return np.round(np.asarray(a, dtype=float), DECIMALS)


def json_default(packed: bool = False):
    """json.dumps's ``default`` for a payload's arrays: lists, or packed float32 (see the module doc); a
    coordinate that is not finite is refused (ValueError), as a NaN in a list is by allow_nan=False."""
    def default(value):
        if not isinstance(value, np.ndarray):
            raise TypeError(f"{type(value).__name__} is not JSON")
        if not packed or value.dtype.kind != "f":
            return value.tolist()
        if not np.all(np.isfinite(value)):
            raise ValueError("a packed array holds a value that is not finite")
        data = np.ascontiguousarray(value, dtype="<f4").tobytes()
        return {"f32": base64.b64encode(data).decode("ascii"), "shape": list(value.shape)}
    return default


def cell_fields(x: np.ndarray, y: np.ndarray, cells: np.ndarray, mu: np.ndarray, lam: np.ndarray) -> dict:
    """Per triangle: largest principal stretch and psi(F) = mu/2 (tr C - 2) - mu ln J + lam/2 (ln J)^2.

    F maps the rest triangle onto the deformed one (exact for P1), C = F^T F, J = det F.
    """
    from ..io.xdmf import cell_gradients, largest_stretch
    F = cell_gradients(x, y, cells)
    tr = np.einsum("nij,nij->n", F, F)              # tr C
    J = np.linalg.det(F)
    with np.errstate(invalid="ignore", divide="ignore"):
        lnJ = np.log(J)
    psi = mu / 2 * (tr - 2) - mu * lnJ + lam / 2 * lnJ ** 2
    return {"stretch": _round(largest_stretch(F)), "energy_density": _round(np.where(J > 0, psi, np.nan))}


def _lame_by_tag(design, tags: dict) -> tuple[dict, dict]:
    from ..terms.elasticity import lame
    from ..mesh.geometry import body_tag_name
    names = {**{body_tag_name(b): b.material for b in design.bodies},
             **{f"bone:{b.name}": b.material for b in design.bones}}
    mu, lam = {}, {}
    for name, tag in tags.items():
        m = design.materials[names[name]] if name in names else None
        mu[tag], lam[tag] = lame(m.E, m.nu) if m is not None else (0.0, 0.0)
    return mu, lam


_FACES: dict = {}          # the last mesh's boundary faces, by a digest of its cells and regions


def boundary_faces(tets: np.ndarray, regions: np.ndarray, x: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Triangles on the boundary of each region of a tetrahedral mesh, with their region (the last mesh's
    kept: a 3D drag's frames move the nodes, not the cells; 46 ms of a frame at 10k DOFs). With the node
    coordinates x, each triangle is ordered counter-clockwise seen from outside its region (the page draws
    only the ones that face the viewer)."""
    import hashlib
    key = hashlib.sha1(np.ascontiguousarray(tets).tobytes() + np.ascontiguousarray(regions).tobytes()
                       + (b"x" if x is not None else b"")).hexdigest()
    if key not in _FACES:
        _FACES.clear()
        _FACES[key] = _boundary_faces(tets, regions, x)
    return _FACES[key]


def _boundary_faces(tets: np.ndarray, regions: np.ndarray, x: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Triangles on the boundary of each region of a tetrahedral mesh, with their region."""
    faces = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]])
    if x is not None:                 # outward: away from the tetrahedron's fourth vertex
        opposite = np.concatenate([tets[:, 3], tets[:, 2], tets[:, 1], tets[:, 0]])
        a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
        inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), x[opposite] - a) > 0
        faces[inward] = faces[inward][:, [0, 2, 1]]
    owner = np.tile(regions, 4)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    # a face shared by two cells of the same region is interior; by two regions, it bounds both
    order = np.argsort(inverse, kind="stable")
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    second = np.minimum(starts + 1, len(order) - 1)
    same = (counts == 2) & (owner[order[starts]] == owner[order[second]])
    keep = ~same[inverse]
    return faces[keep], owner[keep]


def mesh_payload(model, topology: bool = True, fields: bool = True) -> dict:
    """The deformed state of a Session's model (serial) as plain lists; see the module doc.

    topology=False leaves out what a client holding this mesh has already (``x``, ``cells``, ``regions``,
    ``region_names``, ``body_tag``): a frame of a drag on the same mesh sends its deformed nodes ``y``
    (moved nodes change ``x`` too; the page draws ``y``). fields=False leaves out the per-cell fields.
    """
    from ..io.xdmf import snapshot

    snap = snapshot(model)
    x, u, cells, regions = snap.x, snap.u, np.asarray(snap.cells), np.asarray(snap.regions)
    y = x + u
    tags = dict(model.tm.tags)
    out: dict = {"dim": int(x.shape[1])}
    if topology:
        out.update(region_names={str(v): k for k, v in tags.items()}, body_tag=int(snap.body_tag))
    if x.shape[1] == 2:
        if fields:
            mu, lam = _lame_by_tag(snap.design, tags)
            out["fields"] = cell_fields(x, y, cells, np.vectorize(mu.get)(regions).astype(float),
                                        np.vectorize(lam.get)(regions).astype(float))
    else:
        cells, regions = boundary_faces(cells, regions, x)
        used, cells = np.unique(cells, return_inverse=True)
        cells = cells.reshape(-1, 3)
        x, y = x[used], y[used]
    out["y"] = _rounded(y)
    if topology:
        out.update(x=_rounded(x), cells=cells.astype(int).tolist(), regions=regions.astype(int).tolist())
    out["cables"] = [{"name": c["name"], "kind": c["kind"], "via_rest": _rounded(c["rest"]),
                      "via": _rounded(c["deformed"]), "tension": float(c["tension"]),
                      "length": float(c["length"]), "rest_length": float(c["rest_length"]),
                      "slack": bool(c["tension"] <= 0.0)} for c in snap.cables]
    out["markers"] = {name: _round(p) for name, p in snap.markers.items()}
    out["objects"] = [{"name": o["name"], "outline": _round(o.get("outline", np.zeros((0, 2)))),
                       "points": _round(o.get("points", np.zeros((0, 2)))),
                       "normal": _round(o.get("normal", np.zeros((0, 2)))),
                       "friction": _round(o.get("friction", np.zeros((0, 2))))} for o in snap.objects]
    return out

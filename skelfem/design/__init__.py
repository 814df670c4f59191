"""Design files: read a TOML design, apply ``--set`` overrides, validate (no DOLFINx import).

The contract is the design format (docs: design files). Every problem is a
:class:`DesignError` whose message names the file and the key, raised before
any meshing. ``spec`` holds the validated dataclasses, ``table`` the typed
reading of TOML tables, ``shapes`` the body, bones and materials, ``sections``
every other section (one reader per ingredient), ``parse`` the entry points,
``solids``/``occ`` the 3D checks on OpenCASCADE, ``resources`` the size
estimate behind ``--force``.
"""
from .parse import apply_override, changed_keys, flatten, load_design, parse_design, read_toml
from .spec import (FORMAT, Body, Bone, CableSpec, ContactSpec, Design, DesignError, DynamicsSpec,
                   FabricationSpec, GroundSpec, LoadSpec, Material, MeshSpec, PinSpec, SolverSpec, TractionSpec)

__all__ = ["FORMAT", "Body", "Bone", "CableSpec", "ContactSpec", "Design", "DesignError", "DynamicsSpec",
           "FabricationSpec", "GroundSpec", "LoadSpec", "Material", "MeshSpec", "PinSpec", "SolverSpec",
           "TractionSpec", "apply_override", "changed_keys", "flatten", "load_design", "parse_design", "read_toml"]

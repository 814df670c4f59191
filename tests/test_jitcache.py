"""The in-process memo of FFCx's compiled modules (skelfem.jitcache)."""
import ffcx.parameters
import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from skelfem.runtime import jitcache


def _assemble_area(n: int, power: int) -> float:
    m = mesh.create_unit_square(MPI.COMM_SELF, n, n)
    x = ufl.SpatialCoordinate(m)
    return fem.assemble_scalar(fem.form(x[0] ** power * ufl.dx))


def test_a_second_mesh_finds_its_modules_in_memory():
    jitcache.install()
    jitcache.install()                                   # idempotent: wrapped once
    from ffcx.codegeneration import jit
    assert not hasattr(jit.get_cached_module.lookup, "lookup")
    _assemble_area(2, 1)                                 # may compile (then not memoised yet)
    _assemble_area(2, 1)                                 # found on disk: memoised
    calls = []
    lookup = jit.get_cached_module.lookup
    try:
        jit.get_cached_module = jitcache._memoised(lambda *a: calls.append(a) or lookup(*a))
        assert abs(_assemble_area(3, 1) - 0.5) < 1e-12   # same forms on a new mesh: no disk look-up
        assert calls == []
        assert abs(_assemble_area(3, 3) - 0.25) < 1e-12  # a changed form gets its own module
        assert len(calls) >= 1
    finally:
        jit.get_cached_module = jitcache._memoised(lookup)


def test_parameters_are_copies():
    jitcache.install()
    p = ffcx.parameters.get_parameters({})
    p["scalar_type"] = "nonsense"
    assert ffcx.parameters.get_parameters({})["scalar_type"] != "nonsense"
    assert np.isfinite(_assemble_area(2, 2))

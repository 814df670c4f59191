"""Memory of big runs: solution.xdmf written as it is made, stretches in pieces, big blocks unmapped when
freed, a big mesh's cell tree dropped once the model is built."""
import subprocess
import sys

import meshio
import numpy as np
import pytest

from skelfem.io import xdmf


def _grid(rng, gdim_cells):
    n = 40
    points = rng.random((n, 3)) * 10.0
    blocks = [(kind, (rng.integers(0, n - k, m)[:, None] + np.arange(k)).astype(np.int64))
              for kind, k, m in gdim_cells]
    point_data = {"displacement": rng.standard_normal((n, 3)), "contact_force": rng.standard_normal((n, 3))}
    cell_data = {name: [rng.standard_normal(len(c)) for _, c in blocks] for name in ("region", "stretch")}
    return points, blocks, point_data, cell_data


@pytest.mark.parametrize("cells", [[("tetra", 4, 30)], [("triangle", 3, 25), ("line", 2, 6)]],
                         ids=["one block", "mixed with cables"])
def test_streamed_xdmf_is_meshios_file_byte_for_byte(tmp_path, monkeypatch, cells):
    points, blocks, point_data, cell_data = _grid(np.random.default_rng(3), cells)
    monkeypatch.setattr(xdmf, "XML_ROWS", 7)          # several pieces per array
    xdmf.write_xml_grid(tmp_path / "ours.xdmf", points, blocks, point_data, cell_data)
    meshio.xdmf.write(tmp_path / "meshio.xdmf", meshio.Mesh(points, blocks, point_data=point_data,
                                                            cell_data=cell_data), data_format="XML")
    assert (tmp_path / "ours.xdmf").read_bytes() == (tmp_path / "meshio.xdmf").read_bytes()
    m = meshio.read(tmp_path / "ours.xdmf")
    assert np.array_equal(m.points, points)
    assert [c.type for c in m.cells] == [k for k, _ in blocks]
    assert all(np.array_equal(c.data, b) for c, (_, b) in zip(m.cells, blocks))


def test_stretches_in_pieces_equal_one_piece(monkeypatch):
    rng = np.random.default_rng(5)
    x = rng.random((50, 3))
    y = x + 0.1 * rng.standard_normal((50, 3))
    cells = rng.integers(0, 46, 23)[:, None] + np.arange(4)
    whole = xdmf.largest_stretch(xdmf.cell_gradients(x, y, cells))
    monkeypatch.setattr(xdmf, "STRETCH_CHUNK", 5)
    assert np.array_equal(xdmf.cell_stretches(x, y, cells), whole)


ALLOCATE = """
import ctypes, sys, numpy as np
class MallInfo(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]
libc = ctypes.CDLL("libc.so.6"); libc.mallinfo2.restype = MallInfo
from petsc4py import PETSc                     # MPI_Init
from skelfem.runtime import memory
if sys.argv[1] == "allow":
    assert memory.allow_mmap()
before = libc.mallinfo2().hblkhd
block = np.ones(4 << 20)                        # 32 MB
print((libc.mallinfo2().hblkhd - before) / 2**20)
"""


def test_big_blocks_are_mapped_on_their_own_after_mpi_init():
    """MPI_Init leaves every big block in the one heap; allow_mmap maps them again (glibc only)."""
    def mapped(mode):
        out = subprocess.run([sys.executable, "-c", ALLOCATE, mode], capture_output=True, text=True, check=True)
        return float(out.stdout.split()[-1])
    assert mapped("allow") >= 32.0
    assert mapped("as-is") < 1.0, "MPI_Init no longer turns mmap off: allow_mmap may not be needed any more"


def test_a_big_mesh_drops_its_cell_tree_once_the_model_is_built(monkeypatch):
    from _designs import strip
    from skelfem.mesh import keep, points
    from skelfem.session import Session
    monkeypatch.setattr(points, "TREE_CELLS", 0)
    with Session(strip(size=3.0)) as s:
        assert keep.peek(s.model.mesh, "cell_tree") is None
        x = s.model.mesh.geometry.x[:3, :2].mean(axis=0)
        assert points.locate_cells(s.model.mesh, x[None])[0] >= 0       # made again when needed
        assert s.solve().converged
    monkeypatch.setattr(points, "TREE_CELLS", 10**9)
    with Session(strip(size=3.0)) as s:
        assert keep.peek(s.model.mesh, "cell_tree") is not None


def test_the_jacobian_leaves_no_packed_coefficients_behind():
    """The pack serves the energy, residual and Jacobian at one state, then goes (it would sit beside the
    multigrid's set-up); the next evaluation packs again and gives the same residual."""
    from _designs import strip
    from skelfem.session import Session
    with Session(strip(size=3.0)) as s:
        m = s.model
        x = m.u.vector.copy()
        b0, b1 = x.duplicate(), x.duplicate()
        m.residual(x, b0)
        assert m._packs.packs
        A = m.create_matrix()
        m.jacobian(x, A)
        assert not m._packs.packs
        m.residual(x, b1)
        assert np.array_equal(b0.array, b1.array)
        A.destroy()


def test_kept_values_go_with_their_object_and_when_forgotten():
    """mesh/keep.py holds values beside an object, not on it: made once, dropped when forgotten and
    when the object is collected (nothing outlives a mesh)."""
    import gc

    from skelfem.mesh import keep

    class Thing:
        pass
    a, b, made = Thing(), Thing(), []
    assert keep.kept(a, "x", lambda: made.append(1) or "value") == "value"
    assert keep.kept(a, "x", lambda: made.append(1) or "other") == "value" and made == [1]
    keep.kept(a, "y", lambda: 2)
    keep.kept(b, "x", lambda: 3)
    keep.forget(a, "x")
    assert keep.peek(a, "x") is None and keep.peek(a, "y") == 2 and keep.peek(b, "x") == 3
    key = (id(b), "x")
    del b
    gc.collect()
    assert key not in keep._KEPT
    keep.forget(a)
    assert keep.peek(a, "y") is None

"""Shared fixtures: design dicts, the finger4 session, mpirun runs, picture checks.

Plain helpers live beside it: ``_designs`` (design dicts and TOML text),
``_studies`` (loading a study script), ``_taylor`` (Taylor remainders).
"""
import gc
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _designs import strip

os.environ.setdefault("MPLBACKEND", "Agg")
logging.getLogger().setLevel(logging.WARNING)

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = ROOT / "geometry"
SKELFEM = str(Path(sys.executable).parent / "skelfem")
MPI_ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1", "OMPI_MCA_mpi_yield_when_idle": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MPLBACKEND": "Agg"}


@pytest.fixture(autouse=True)
def _collect():
    yield
    gc.collect()


@pytest.fixture(autouse=True)
def _fresh_log():
    """A test starts with skelfem's logger as importing leaves it (propagating, no handler): a command run
    by an earlier test points it at that test's captured stderr and stops propagation (cli.common), which
    hid later tests' warnings from caplog and wrote to a closed file."""
    log = logging.getLogger("skelfem")
    log.handlers[:], log.propagate = [], True
    log.setLevel(logging.NOTSET)
    yield


# -- designs ------------------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def strip_design():
    """strip(**params) -> a fresh design dict: soft strip, pinned base, one tendon, a tip marker.

    The same function as _designs.strip, which helpers outside test functions import.
    """
    return strip


@pytest.fixture(scope="module")
def finger4():
    """A Session on geometry/finger4.toml at mesh size 3 (one per test module; tests may change its state)."""
    from skelfem import Session
    session = Session(GEOMETRY / "finger4.toml", ["mesh.size=3"])
    yield session
    session.close()


@pytest.fixture(scope="module")
def editor(tmp_path_factory):
    """A running editor server (127.0.0.1, a free port) on a copy of geometry/finger.toml."""
    from skelfem.editor.server import Editor
    folder = tmp_path_factory.mktemp("designs")
    shutil.copy(GEOMETRY / "finger.toml", folder / "finger.toml")
    ed = Editor(folder / "finger.toml", port=0).start()
    yield ed
    ed.stop()


# -- subprocesses under mpirun --------------------------------------------------------------------------
class Mpirun:
    """Runs commands serially or under ``mpirun -n N`` with the environment the Makefile sets."""

    env = MPI_ENV
    skelfem = SKELFEM

    def command(self, args, ranks: int = 1) -> list:
        args = [str(a) for a in args]
        return (["mpirun", "-n", str(ranks)] + args) if ranks > 1 else args

    def run(self, args, ranks: int = 1, timeout: float = 300) -> subprocess.CompletedProcess:
        return subprocess.run(self.command(args, ranks), env=self.env, capture_output=True, text=True,
                              timeout=timeout)


@pytest.fixture(scope="session")
def mpirun() -> Mpirun:
    if shutil.which("mpirun") is None:
        pytest.skip("needs mpirun")
    return Mpirun()


# -- pictures -------------------------------------------------------------------------------------------
def check_picture(path, min_width: int = 300, min_height: int = 200, min_ink: float = 0.05,
                  min_colour: float = 0.002) -> np.ndarray:
    """Assert that path is a PNG of at least the given size with a drawing on it; returns the image.

    The background is the most common colour. At least a fraction min_ink of
    the pixels must differ from it (empty matplotlib axes with ticks and
    labels reach about 0.02; the pictures here 0.1 to 0.3), and at least a
    fraction min_colour must be coloured, not grey (max - min of R, G, B
    above 40 of 255): every picture here draws in colour (bodies, cables,
    curves), so a frame with grey text only fails.
    """
    import matplotlib.image as mpimg

    path = Path(path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    img = mpimg.imread(str(path))
    assert img.ndim == 3 and img.shape[2] in (3, 4), img.shape
    h, w = img.shape[:2]
    assert w >= min_width and h >= min_height, f"{path.name}: {w} x {h} pixels, expected >= {min_width} x {min_height}"
    rgb = np.round(np.asarray(img[:, :, :3], dtype=float) * 255).astype(np.int64)
    codes = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
    counts = np.unique(codes, return_counts=True)[1]
    ink = 1.0 - counts.max() / codes.size
    assert ink >= min_ink, f"{path.name}: only {ink:.2%} of the pixels differ from the background"
    colour = float(np.mean(rgb.max(axis=2) - rgb.min(axis=2) > 40))
    assert colour >= min_colour, f"{path.name}: only {colour:.2%} of the pixels are coloured"
    return img


@pytest.fixture(scope="session")
def picture():
    """check_picture(path, min_width, min_height, min_ink, min_colour): a real, non-blank PNG."""
    return check_picture


def pytest_collection_modifyitems(config, items):
    """A test that uses the mpirun fixture runs under mpirun: it is marked mpi (make test runs those
    after the parallel phase, one at a time, so two ranks never compete with another test's worker)."""
    for item in items:
        if "mpirun" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.mpi)

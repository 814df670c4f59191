import gc
import logging
import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
logging.getLogger().setLevel(logging.WARNING)


@pytest.fixture(autouse=True)
def _collect():
    yield
    gc.collect()

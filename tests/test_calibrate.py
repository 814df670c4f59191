"""Calibration: sensitivities of every parameter kind, recovery, identifiability, coverage, bad data."""
import math

import numpy as np
import pytest

from skelfem import Session
from skelfem.analysis.caldata import DataError, live_keys, prepare_data
from skelfem.analysis.calibrate import Rows, calibrate, misfit, synthesize
from skelfem.design import load_design, parse_design

from conftest import GEOMETRY

FINGER = GEOMETRY / "finger.toml"
STIFFNESSES = ["materials.ecoflex.E", "materials.pla.E", "cables.flexor.stiffness",
               "cables.lig1_palmar.stiffness", "cables.lig1_dorsal.stiffness",
               "cables.lig2_palmar.stiffness", "cables.lig2_dorsal.stiffness"]
TIP = ["markers.tip.x", "markers.tip.y"]


def heavy_finger(size=4.0):
    """finger.toml, coarse, under gravity across the finger (the weight bends it) with a pretensioned ligament."""
    raw = load_design(FINGER, [f"mesh.size={size}"]).raw
    raw["gravity"] = {"acceleration": [-9.81, -2.0]}
    for c in raw["cables"]:
        if c["name"] == "lig1_dorsal":
            c["pretension"] = 0.3
    return parse_design(raw, str(FINGER))


@pytest.fixture(scope="module")
def heavy():
    with Session(heavy_finger()) as s:
        s.solver.rtol, s.solver.atol = 0.0, 1e-11      # tight equilibria for the differences
        yield s


@pytest.fixture(scope="module")
def finger():
    with Session(FINGER, ["mesh.size=4.0"]) as s:
        yield s


def test_live_keys_are_the_model_parameters(heavy, finger):
    for s in (heavy, finger):
        assert set(live_keys(s.design)) == set(s.model.parameters())


# every kind: E, nu, stiffness, pretension, a contraction offset, density, gravity
KINDS = ["materials.ecoflex.E", "materials.ecoflex.nu", "materials.pla.E", "cables.flexor.stiffness",
         "cables.lig1_dorsal.pretension", "cables.flexor.contraction", "materials.ecoflex.density",
         "gravity.acceleration.y"]
COLUMNS = TIP + ["cables.flexor.tension", "cables.lig1_dorsal.tension", "pins.base.reaction.x",
                 "pins.base.reaction.y"]


def _problem(session, values=None):
    data = {"cables.flexor.contraction": [3.0, 6.0], **{c: [0.0, 0.0] for c in COLUMNS}}
    if values is not None:
        data.update({c: list(values[:, j]) for j, c in enumerate(COLUMNS)})
    return prepare_data(session.design, data, KINDS)


def test_sensitivities_of_every_parameter_kind(heavy):
    data = _problem(heavy)
    theta = np.array([p.initial for p in data.parameters])
    assert data.parameters[KINDS.index("cables.flexor.contraction")].offset
    Y, J, _ = Rows(heavy, data).run(theta)
    scale = np.array([p.scale for p in data.parameters])
    fds = []
    for j, key in enumerate(KINDS):
        h = 1e-5 * scale[j]
        e = np.zeros(len(theta))
        e[j] = h
        yp = Rows(heavy, data).run(theta + e, jacobian=False)[0]
        ym = Rows(heavy, data).run(theta - e, jacobian=False)[0]
        fds.append((yp - ym) / (2 * h))
        assert np.abs(fds[-1]).max() > 1e-9, key              # the parameter moves something
    fds = np.array(fds)                                         # (parameters, rows, columns)
    # each column's size: its largest change per relative change of a parameter
    size = np.max(np.abs(fds) * scale[:, None, None], axis=(0, 1))
    for j, key in enumerate(KINDS):
        err = np.abs(J[:, :, j] - fds[j]) * scale[j] / size
        # the differences carry the Newton tolerance (|R| ~ 1e-9 N at x*): /2h = 1e-4 of a reaction for nu
        assert err[:, :4].max() < 2e-5 and err.max() < 5e-4, (key, err.max(), J[:, :, j], fds[j])


def test_misfit_gradient_against_central_differences(heavy):
    data0 = _problem(heavy)
    theta0 = np.array([p.initial for p in data0.parameters])
    Y = Rows(heavy, data0).run(theta0, jacobian=False)[0]
    rng = np.random.default_rng(1)
    data = _problem(heavy, Y + rng.normal(0, 0.05, Y.shape))
    theta = theta0 * (1 + 0.01 * rng.standard_normal(len(theta0))) + 0.01 * (theta0 == 0)
    f, g = misfit(heavy, data, theta)
    scale = np.array([p.scale for p in data.parameters])
    for j, key in enumerate(KINDS):
        h = 1e-5 * scale[j]
        e = np.zeros(len(theta))
        e[j] = h
        fd = (misfit(heavy, data, theta + e, False)[0] - misfit(heavy, data, theta - e, False)[0]) / (2 * h)
        # PLA's E moves f by 1e-9 per 1e-5: the Newton tolerance limits the difference to ~1e-3 there
        assert abs(g[j] - fd) <= 1e-3 * abs(fd) + 1e-7 * np.max(np.abs(g * scale)) / scale[j], (key, g[j], fd)
        if key != "materials.pla.E":
            assert abs(g[j] - fd) <= 1e-4 * abs(fd) + 1e-7 * np.max(np.abs(g * scale)) / scale[j], (key, g[j], fd)

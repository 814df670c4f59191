"""The discrete adjoint through time (skelfem.adjoint): gradients of timed marker targets with
respect to schedule knots, against central differences, and its cost against a forward run."""
import time

import numpy as np
import pytest

from _designs import strip
from skelfem import Session
from skelfem.adjoint import TimedTarget, knot_weights, schedule_gradient


def flick(integrator="bdf2", size=4.0, dt=0.01, duration=0.08, damping=None):
    d = strip(length=40.0, width=8.0, size=size, contraction=0.0, k=5.0, E=0.5)
    for m in d["materials"].values():
        m["density"] = 1100.0
    d["cables"][0]["schedule"] = [[0.0, 0.5], [0.03, 2.0], [0.06, 1.5]]   # taut throughout
    d["dynamics"] = {"dt": dt, "duration": duration, "integrator": integrator}
    if damping:
        d["dynamics"]["damping"] = damping
    d["solver"] = {"rtol": 1e-12, "atol": 1e-13}
    return d


TARGETS = [TimedTarget("tip", 0.08, np.array([12.0, 36.0])), TimedTarget("tip", 0.035, np.array([6.0, 39.0]))]


def test_knot_weights_are_the_interpolation():
    times = np.array([0.0, 0.03, 0.06])
    for t in (0.0, 0.01, 0.03, 0.05, 0.06, 0.2):
        w = knot_weights(times, t)
        assert w.sum() == pytest.approx(1.0) and w @ np.array([0.5, 2.0, 1.5]) == pytest.approx(
            np.interp(t, times, [0.5, 2.0, 1.5]))


@pytest.mark.slow
@pytest.mark.parametrize("integrator, damping", [("euler", None), ("bdf2", {"mass": 5.0})])
def test_adjoint_gradient_matches_central_differences(integrator, damping):
    d = flick(integrator, damping=damping)
    with Session(d) as s:
        r = schedule_gradient(s, TARGETS)
        assert r.report.cuts == 0
        base = np.array(d["cables"][0]["schedule"], float)
        fd = np.zeros(len(base))
        eps = 1e-4
        for k in range(len(base)):
            values = []
            for sign in (1.0, -1.0):
                sched = base.copy()
                sched[k, 1] += sign * eps
                s.set({"cables.flexor.schedule": sched.tolist()})
                values.append(schedule_gradient(s, TARGETS).value)
            fd[k] = (values[0] - values[1]) / (2 * eps)
    g = r.gradient["flexor"]
    rel = np.abs(fd - g).max() / np.abs(fd).max()
    assert rel < 1e-5, (g, fd, rel)                      # measured: 6e-8 (Euler), 8e-8 (BDF2, mass damping)


@pytest.mark.slow
def test_gradient_costs_at_most_one_and_a_half_forward_runs():
    with Session(flick(size=0.7, dt=0.004)) as s:       # 1764 DOFs, 20 steps
        schedule_gradient(s, TARGETS)                    # compiles the mass matrix form once
        ratios = []
        for _ in range(3):                               # best of three: the machine may be busy
            t0 = time.perf_counter()
            s.run()
            forward = time.perf_counter() - t0
            r = schedule_gradient(s, TARGETS)
            ratios.append((r.forward_time + r.adjoint_time) / forward)
    assert min(ratios) <= 1.5, ratios                   # measured: 1.2

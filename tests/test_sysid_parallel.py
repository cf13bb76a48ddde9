"""Both cores for the refinements' finite-difference Jacobians (rtlift/sysid/parallel.py, issue 48):
the same numbers as one core, bit for bit, and never an error where the child cannot help."""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy import optimize, signal

from rtlift.core.records import SisoRecord
from rtlift.sysid import parallel
from rtlift.sysid.common import SisoOptions
from rtlift.sysid.identify import identify_siso
from rtlift.sysid.parallel import Halves


@pytest.fixture(autouse=True)
def both_cores(monkeypatch):
    """This file's tests on both cores (tests/conftest.py keeps the rest of the suite on one)."""
    monkeypatch.delenv(parallel.CORES_ENV, raising=False)


def test_one_core_when_told_starts_no_child(monkeypatch):
    """``RTLIFT_SYSID_CORES=1``: no child, the serial map; the two lanes run here, in order."""
    monkeypatch.setenv(parallel.CORES_ENV, "1")
    with Halves(_residual) as workers:
        assert workers.pid is None
        got = workers(_residual, _points())
    for g, x in zip(got, _points(), strict=True):
        np.testing.assert_array_equal(g, _residual(x))
    me = os.getpid()
    assert parallel.two_lanes([os.getpid, os.getpid]) == [me, me]


def _points(n: int = 7) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [rng.normal(size=4) for _ in range(n)]


def _residual(x: np.ndarray) -> np.ndarray:
    t = np.linspace(0.0, 1.0, 500)
    return np.sin(x[0] * t + x[1]) * np.exp(-x[2] * t) + x[3] * t**2


def test_halves_map_is_the_serial_map_bit_for_bit_and_reaps_its_child():
    with Halves(_residual) as workers:
        assert workers.pid is not None                       # a child was started (Linux: fork)
        got = workers(_residual, _points())
        again = workers(_residual, _points(3))               # the same child serves the next Jacobian
        pid = workers.pid
    assert workers.pid is None and workers.conn is None
    try:
        os.waitpid(pid, os.WNOHANG)
        raise AssertionError("the child was not waited for")
    except ChildProcessError:
        pass
    for g, x in zip(got + again, _points() + _points(3), strict=True):
        assert np.array_equal(g, _residual(x))


def test_a_point_the_child_cannot_evaluate_is_evaluated_here():
    parent = os.getpid()

    def fragile(x: np.ndarray) -> np.ndarray:
        if os.getpid() != parent and x[0] > 0:
            raise FloatingPointError("only in the child")
        return _residual(x)

    with Halves(fragile) as workers:
        got = workers(fragile, _points())
    assert all(np.array_equal(g, _residual(x)) for g, x in zip(got, _points(), strict=True))
    # without a child (closed): every point evaluated here, the same numbers
    workers = Halves(fragile)
    assert all(np.array_equal(g, _residual(x)) for g, x in zip(workers(fragile, _points()), _points(), strict=True))


def test_a_short_residual_is_refined_on_one_core(monkeypatch):
    started = []
    monkeypatch.setattr(Halves, "_start", lambda self: started.append(self))
    parallel.least_squares(_residual, np.ones(4), parallel.MIN_SAMPLES - 1, max_nfev=3)
    assert not started
    parallel.least_squares(_residual, np.ones(4), parallel.MIN_SAMPLES, max_nfev=3)
    assert len(started) == 1


def test_least_squares_on_both_cores_ends_where_one_core_does():
    rng = np.random.default_rng(0)
    truth = np.array([7.0, 0.3, 1.5, -0.4])
    target = _residual(truth) + 0.01 * rng.normal(size=500)

    def res(x: np.ndarray) -> np.ndarray:
        return _residual(x) - target

    x0 = np.array([6.0, 0.0, 1.0, 0.0])
    one = optimize.least_squares(res, x0, x_scale="jac", ftol=1e-12, xtol=1e-12)
    both = parallel.least_squares(res, x0, parallel.MIN_SAMPLES, x_scale="jac", ftol=1e-12, xtol=1e-12)
    assert one.nfev == both.nfev and np.array_equal(one.x, both.x)
    assert np.max(np.abs(both.x - truth)) < 0.05


def test_identify_output_dynamics_is_bit_for_bit_the_one_core_model(monkeypatch):
    """A Wiener-Hammerstein plant (tanh between two second-order blocks): the model the refinements
    reach with their Jacobians shared is the one-core model to the last bit."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=1200)
    x = signal.lfilter([0.2, 0.1], [1.0, -1.2, 0.5], u)
    y = signal.lfilter([0.3], [1.0, -0.7], np.tanh(x)) + 0.01 * rng.normal(size=u.size)
    rec = SisoRecord(np.arange(u.size) / 100.0, u, y, {"fs_hz": "100"}, "wh")
    opt = SisoOptions(orders=(3,), knots=8, more_knots=(), max_nfev=25)
    monkeypatch.setattr(parallel, "MIN_SAMPLES", 100)         # a short record shares its Jacobians too
    both = identify_siso(rec, "wiener_hammerstein", options=opt).to_dict()
    monkeypatch.setattr(parallel, "WORKERS", False)
    one = identify_siso(rec, "wiener_hammerstein", options=opt).to_dict()
    assert both == one
    assert both["provenance"]["splits_refined"] >= 1


def test_two_lanes_gives_the_serial_results_and_exceptions_in_order():
    parent = os.getpid()
    tasks = [lambda: (os.getpid() != parent, _residual(_points()[0])),      # the child's lane
             lambda: _residual(_points()[1]),
             lambda: np.linalg.cholesky(-np.eye(2))]                          # a LinAlgError (a ValueError)
    first, second, third = parallel.two_lanes(tasks)
    assert first[0] is True and np.array_equal(first[1], _residual(_points()[0]))
    assert np.array_equal(second, _residual(_points()[1]))
    assert isinstance(third, np.linalg.LinAlgError)
    # a result the child cannot send back (a lambda does not pickle): the task is run here instead
    lone = parallel.two_lanes([lambda: (os.getpid(), lambda: 0), lambda: 1])
    assert lone[0][0] == parent and lone[1] == 1

"""Fixtures. The synthetic models and inputs the tests share with the benchmarks live in
:mod:`testkit.synthetic`."""

from __future__ import annotations

import signal

import numpy as np
import pytest


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The suite runs in two pytest-xdist workers (``-n 2 --dist loadgroup``, pyproject.toml):
    every test over real pseudo-terminals (marked ``pty``: a simulated device paced by the wall
    clock, a host reading it at 400 Hz) in one group, run one after another by one worker, so
    that no two real-time runs share the two cores; every other module whole in a group of its
    own, so that its module fixtures are built once. The real-time group waits mostly on the
    clock, the other worker computes meanwhile. (Before xdist's own hook, which reads the marks.)"""
    for item in items:
        group = "realtime" if item.get_closest_marker("pty") else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def model_file(tmp_path_factory):
    """A model identified on the bench and tuned for the observer, as a file (shared by the
    live-observe and replay tests; a module may define its own ``model_file``)."""
    from rtlift.model.modelfile import save_model
    from tests.test_observer_bench import bench_model

    path = tmp_path_factory.mktemp("model") / "model.json"
    model = bench_model(("random",))
    save_model(model, path, observer=model.observer_config)
    return path


# A run started in the background of a non-interactive shell (`bash -c '... &'`) inherits SIGINT
# ignored, and so would every rtlift process a test starts: the tests that stop one with Ctrl-C
# would wait for ever. A Python handler here is reset to the default in each child at exec, so the
# children see Ctrl-C as a user's terminal delivers it.
signal.signal(signal.SIGINT, signal.default_int_handler)

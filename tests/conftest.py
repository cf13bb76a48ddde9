"""Fixtures. The synthetic models and inputs the tests share with the benchmarks live in
:mod:`testkit.synthetic`."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from rtlift.sysid.parallel import CORES_ENV

CPU_NICE = 19
"""The niceness of a worker while it runs a computing test (every test not marked ``pty``)."""

# The identification on one core in the suite (the same numbers: rtlift/sysid/parallel.py): its
# workers already fill both cores beside the real-time loops; tests/test_sysid_parallel.py turns
# the second core on for itself.
os.environ.setdefault(CORES_ENV, "1")


def _favour_realtime() -> bool:
    """Whether a worker can hand the cores back to a real-time test after a computing one: only a
    privileged process may lower its niceness again (CI runs as root)."""
    return hasattr(os, "geteuid") and os.geteuid() == 0 and hasattr(os, "setpriority")


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject.toml): one worker per core, and one more where the real-time tests
    can be favoured (:func:`pytest_runtest_setup`). The real-time group is one worker's for the
    whole run (:func:`pytest_collection_modifyitems`) and mostly waits on the clock; without the
    extra worker a core idles under it. ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still wins."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores + 1 if _favour_realtime() else cores


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The suite runs in pytest-xdist workers (``-n auto --dist loadgroup``, pyproject.toml):
    every test over real pseudo-terminals (marked ``pty``: a simulated device paced by the wall
    clock, a host reading it at 400 Hz) in one group, run one after another by one worker, so
    that no two real-time runs share the cores; every other module whole in a group of its
    own, so that its module fixtures are built once. (Before xdist's own hook, which reads the marks.)

    In a worker the groups are then put in the order they are to start (:func:`_start_order`;
    xdist hands them out in collection order, :func:`pytest_configure`), each group's tests in
    their own order."""
    groups = {}
    for item in items:
        group = "realtime" if item.get_closest_marker("pty") else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
        groups[item] = group
    if os.environ.get("PYTEST_XDIST_WORKER"):
        sizes: dict[str, int] = {}
        for group in groups.values():
            sizes[group] = sizes.get(group, 0) + 1
        items.sort(key=lambda item: _start_order(groups[item], sizes[groups[item]]))


LONGEST_FIRST = (
    "tests/test_interaction_blocks.py", "tests/test_identify_interaction.py",
    "tests/test_diagnose_independent_plant.py", "tests/test_sysid.py", "tests/test_identify_cli.py",
    "tests/test_diagnose_effects.py", "tests/test_diagnose_cli.py", "tests/test_api.py",
    "tests/test_compiled_step.py", "tests/test_sysid_property.py", "tests/test_jit_cache.py",
    "tests/test_identify_paper.py",
)
"""The computing modules that took longest in the clean-clone CI runs at 0e4a2b8 and the two
landings before it (the sum of each module's setup and call times among the 30 slowest of each
run, 90-570 s each), longest first. They start right after the real-time group, so that the run
does not end on one of them with the other workers idle; a module that has become quick here
costs nothing but its place in the order. Not here: test_validate_cli and
test_independent_plant_interaction, which now read the model files test_identify_cli and
test_diagnose_independent_plant identify (:mod:`testkit.shared`): they start later, when those
are written, rather than wait for them beside their makers."""


def _start_order(group: str, size: int) -> tuple:
    """Where a group starts: the real-time group first (one worker runs it whole, one test after
    another: the longest chain), then :data:`LONGEST_FIRST`, then the rest by number of tests,
    most first (pytest-xdist's own order)."""
    if group == "realtime":
        return (0, 0, "")
    if group in LONGEST_FIRST:
        return (1, LONGEST_FIRST.index(group), "")
    return (2, -size, group)


def pytest_configure(config):
    """pytest-xdist's ``loadgroup`` hands the groups out in collection order, once its own
    reordering (by number of tests) is off: the order :func:`pytest_collection_modifyitems` makes."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """A computing test runs at niceness :data:`CPU_NICE`, a real-time one at 0 (and every process
    it starts, which inherits it), so that the scheduler gives the simulated device and the host's
    400 Hz loop a core the moment they wake, however busy the computing workers are. Only where a
    worker can lower its niceness again (:func:`_favour_realtime`); elsewhere nothing changes."""
    if _favour_realtime():
        os.setpriority(os.PRIO_PROCESS, 0, 0 if item.get_closest_marker("pty") else CPU_NICE)


@pytest.fixture(scope="session", autouse=True)
def _shared_results(tmp_path_factory) -> None:
    """Where :mod:`testkit.shared` keeps what one process of the run computes for all: under the
    run's base temporary directory (the workers' common parent under xdist)."""
    from testkit import shared

    base = tmp_path_factory.getbasetemp()
    shared.set_root((base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared")


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

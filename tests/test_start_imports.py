"""What a live start imports before its link opens (issue 47: ``rtlift control`` opens the link
≤ 3 s after it starts when the model's design is cached).

scipy 1.17 rewrites the docstring of every array-API function of scipy.signal, scipy.stats and the
modules they pull in as it imports them: about 1.5 s of CPU on this machine, more than half of a
cached start (docs/results/control.md, "A fast start"). None of it is needed to open the link: the
step is compiled, the monitor's settling time needs only the filter's poles, the observer's filterpy
container is built on first use.

The test runs the real ``rtlift control`` against the bench's serial device over a pseudo-terminal,
under ``python -X importtime``, which writes every import to stderr as it happens, in the same stream
as the command's own lines. So the order on stderr says what was loaded before "link open", and what
was loaded after it but before the monitor's line (the monitor is built after the link opens, just
before the loop starts: an import there stalls a device that is already streaming). A module-level
``from scipy import signal`` anywhere on that path fails this test, and no list of the start's
imports is copied here: an import added to the start is seen as it is run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil_sim.devices import SerialDaq
from hil_sim.hil import HilStream
from testkit.lines import lines_until

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "data" / "bench_model.json"
HEAVY = ("scipy.signal", "scipy.stats", "scipy.optimize", "scipy.interpolate", "scipy.ndimage", "filterpy",
         "control", "matplotlib")


def _heavy(line: str) -> str | None:
    """The heavy module an ``-X importtime`` line reports, else None."""
    if not line.startswith("import time:"):
        return None
    name = line.rsplit("|", 1)[-1].strip()
    return next((name for h in HEAVY if name == h or name.startswith(h + ".")), None)


@pytest.mark.pty
def test_a_cached_start_loads_no_heavy_module_before_the_link_opens(tmp_path):
    stream = HilStream("random", seed=5)
    dev = SerialDaq(stream)
    stream.control = dev.control
    summary = tmp_path / "summary.json"
    cmd = [sys.executable, "-X", "importtime", "-m", "rtlift", "control", "--serial", dev.path, "--model", str(MODEL),
           "--reference", "steps:0.08@0", "--seconds", "2", "--json", str(summary)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        before = lines_until(proc.stderr, "link open", most=100_000)[:-1]   # every import up to the link
        dev.start()
        _, rest = proc.communicate(timeout=120)
    finally:
        dev.stop()
        if proc.poll() is None:                 # a failed wait leaves no host behind
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, rest[-2000:]
    after = rest.splitlines()
    monitor_line = next(i for i, line in enumerate(after) if "monitor thresholds" in line)
    got = json.loads(summary.read_text())
    assert got["gains"]["source"].startswith("cached design"), got["gains"]   # the start measured is the cached one
    assert len(before) > 100                     # -X importtime did report the start's imports
    assert [m for m in map(_heavy, before) if m] == [], "loaded on the way to the link"
    assert [m for m in map(_heavy, after[:monitor_line]) if m] == [], "loaded between the link and the loop"
    assert any(_heavy(line) for line in after[monitor_line:]), "the summary's imports were not seen after the run"


def test_the_observers_filterpy_container_holds_the_steps_own_arrays():
    """``obs.kf`` (built on first use) is filterpy's KalmanFilter over the arrays the step updates:
    a step moves ``kf.x`` and ``kf.P``; ``kf.Q`` is the step's process noise."""
    from filterpy.kalman import KalmanFilter

    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    obs = Observer.from_model(load_model(str(MODEL)))
    kf = obs.kf
    assert isinstance(kf, KalmanFilter) and obs.kf is kf
    x0, p0 = kf.x.copy(), kf.P.copy()
    for k in range(40):
        obs.step(0.004, 0.004, 0.05 + 0.001 * (k % 3))
    assert kf.x is obs._xi and kf.P is obs._P and kf.Q is obs._Q
    assert abs(kf.x - x0).max() > 0 and abs(kf.P - p0).max() > 0
    assert kf.R[0, 0] == obs.config.R

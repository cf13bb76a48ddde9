"""What a live start imports before its link opens (issue 47: ``rtlift control`` opens the link
≤ 3 s after it starts when the model's design is cached).

scipy 1.17 rewrites the docstring of every array-API function of scipy.signal, scipy.stats and the
modules they pull in as it imports them: about 1.5 s of CPU on this machine, more than half of a
cached start (docs/results/control.md, "A fast start"). None of it is needed to open the link: the
step is compiled, the monitor's settling time needs only the filter's poles, the observer's filterpy
container is built on first use. A fresh interpreter does what ``rtlift control`` does up to its
"link open" line — its imports, the model, the cached design, the observer, the controller and the
departure monitor — and says which heavy modules it loaded. A module-level ``from scipy import
signal`` anywhere on that path fails this test; so does an import moved from the start into the run
(the monitor is built after the link opens, so its imports would stall the loop instead).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "data" / "bench_model.json"
HEAVY = ("scipy.signal", "scipy.stats", "scipy.optimize", "scipy.interpolate", "scipy.ndimage", "filterpy",
         "control", "matplotlib")

SCRIPT = f"""
import json, sys
from rtlift.app.commands.control import control_config, run  # noqa: F401 - run's own imports follow
from firmware_io.calibration import Calibration
from firmware_io.convert import Converter
from firmware_io.links import open_link
from rtlift.app.applied import commands_not_applied
from rtlift.app.closed_loop import ControlLoop
from rtlift.app.control import LiftController, gains_text
from rtlift.app.link_options import link_config_from_args
from rtlift.app.live import ObserverLoop, run_live, summary, write_summary
from rtlift.app.reference import parse_reference
from rtlift.app.view.arguments import start_view
from rtlift.app.watch import attach
from rtlift.model.domain import watch_domain
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer
from rtlift.observer.monitor import DepartureMonitor

model = load_model({str(MODEL)!r})
config, gains = control_config(model, True, None, None, None, model_path={str(MODEL)!r})
observer = Observer.from_model(model)
LiftController(model, config)
monitor = DepartureMonitor.for_model(model)
print(json.dumps({{"heavy": [m for m in {HEAVY!r} if m in sys.modules], "source": gains["source"],
                  "compiled": observer.compiled}}))
"""


def test_a_cached_start_loads_no_heavy_module_before_the_link_opens():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["source"].startswith("cached design"), got     # the start measured is the cached one
    assert got["compiled"] is True
    assert got["heavy"] == [], f"loaded on the way to the link: {got['heavy']}"


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

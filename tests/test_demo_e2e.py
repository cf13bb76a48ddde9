"""`rtlift demo` end to end: exit 0, every section of the report with its figures, real numbers.

The demo runs once in the suite, where a new user runs it: right after the README's first
command, ``pip install .``, in a fresh venv with an empty compile cache
(``tests/test_install_fresh.py``, which calls :func:`check_demo`). Three minutes are too many to
spend twice.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

LIVE_SECONDS = 8


def check_demo(out: Path, stdout: str, stderr: str) -> None:
    """What ``rtlift demo --out OUT --live-seconds 8 --quiet`` must have written and printed."""
    assert "Traceback" not in stderr
    report = (out / "report.md").read_text()
    assert len(report) > 2000 and report.rstrip().endswith("![closed loop](figures/closed_loop.png)")
    for section in ("## 1. The standard campaign", "## 2. Identification", "## 3. Validation",
                    "## 4. The Kalman observer live", "## 5. Closing the loop", "## 6. Closed-loop lift tracking"):
        assert section in report
    for fig in ("validate_sine_k0125.png", "validate_sine_k025.png", "validate_random.png", "live_observer.png",
                "closed_loop.png"):
        assert os.path.getsize(out / "figures" / fig) > 10_000
    assert (out / "diagnosis" / "report.md").exists() and (out / "diagnosis" / "model_augmented.json").exists()

    s = json.loads((out / "summary.json").read_text())
    assert s["campaign"]["link"]["lost"] == 0 and s["campaign"]["link"]["crc_errors"] == 0
    for name, paper in (("sine_k0125", 0.9596), ("sine_k025", 0.8654), ("random", 0.9277)):
        assert s["validation"][name]["hybrid"]["corr"] > paper
    live = s["live"]
    assert live["link"]["lost"] == 0 and live["link"]["received"] >= LIVE_SECONDS * 400
    r = live["rmse_vs_truth"]
    assert r["observer"] < r["open_loop_model"] and r["observer"] < r["measurement"]     # issue 44
    d = s["diagnosis"]
    assert [e["name"] for e in d["accepted"]][:1] == ["sensor_resonance"]
    assert abs(d["accepted"][0]["params"]["frequency_hz"] - 24.0) < 2.4          # ±10 %
    for rec in d["records"].values():
        assert rec["rmse_after"] < 0.7 * rec["rmse_before"]
    c = s["closed_loop"]
    ff, fb = c["feedforward"], c["feedback"]
    assert fb["rmse_truth"] < 0.6 * ff["rmse_truth"] and fb["rmse_truth"] < 0.015     # issue 15: ≤ 0.5×, ≤ 0.015
    for row in (ff, fb):
        assert row["lost"] == 0 and row["received"] >= (3 + c["seconds"]) * 400
        assert row["commands_sent"] > 0 and row["watchdog_trips"] == 0
        assert row["commands_applied"] == row["device_applied"] == row["commands_sent"] - row["superseded"]
    assert "paper protocol" in stdout and "diagnosis found: sensor_resonance" in stdout
    assert "feedback / feedforward RMSE" in stdout

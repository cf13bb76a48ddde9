"""``--adapt`` at the run's end (issue 46): a window's diagnosis still running when the loop stops
is waited for (up to its bound), so the summary says what it found, and a swap prepared after the
loop's last burst onset is reported as such — not dropped without a word."""

from __future__ import annotations

import subprocess
import sys
import time

from benchmarks.monitor_null import MODEL
from rtlift.app.adapt import AFTER_S, BEFORE_S, END_WAIT_S, Adapter
from rtlift.app.diagnose_worker import DiagnoseWorker
from rtlift.core.rate import FS_HZ


class _Loop:
    monitor = observer = None


def _idle(self):
    self.proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, text=True)


def _cut_window(ad: Adapter, suspect: str | None = "actuator_fade") -> None:
    """A departure (naming ``suspect``) and the samples after it until its window is cut."""
    start = int(BEFORE_S * FS_HZ)
    ad.on_departure({"sample": start + 1, "t_s": start / FS_HZ, "test": "bias", "suspect": suspect})
    for i in range(start + int(AFTER_S * FS_HZ) + 1):
        ad.after_step(i, 0.02, 0.01, 0.1)


def test_the_runs_end_waits_for_the_diagnosis_in_flight(tmp_path, monkeypatch):
    monkeypatch.setattr(DiagnoseWorker, "_start", _idle)
    monkeypatch.setattr(DiagnoseWorker, "run", lambda self, argv: (time.sleep(1.0), (1, "diagnose: 1.0 s\n"))[1])
    events = []
    ad = Adapter(_Loop(), MODEL, tmp_path, events=events.append, log=events.append)
    _cut_window(ad)
    assert ad.busy
    t0 = time.perf_counter()
    ad.close()                                   # the run ended 0 s into a 1 s diagnosis
    waited = time.perf_counter() - t0
    assert 0.5 < waited < END_WAIT_S
    assert "in flight: waiting up to" in events[0]
    ev = events[-1]
    assert ev["event"] == "diagnosis" and ev["reason"] == "RuntimeError: diagnose: 1.0 s"   # its own answer
    assert not ad.busy


def test_a_swap_prepared_after_the_last_burst_is_reported(tmp_path, monkeypatch):
    monkeypatch.setattr(DiagnoseWorker, "_start", _idle)
    events = []
    ad = Adapter(_Loop(), MODEL, tmp_path, events=events.append)
    ad._busy = True
    ad._ready = {"event": {"event": "diagnosis", "n": 1, "accepted": ["actuator_fade"]}, "at": 0}
    ad.close(0.0)
    assert len(events) == 1 and not events[0].get("swapped")
    assert events[0]["accepted"] == ["actuator_fade"] and "ended before the swap" in events[0]["reason"]
    assert not ad.busy and ad.adaptations == events

"""``--adapt`` at the run's end (issue 46): a window's diagnosis still running when the loop stops
is waited for (up to its bound), so the summary says what it found, and a swap prepared after the
loop's last burst onset is reported as such — not dropped without a word."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

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


def test_a_departure_that_suspects_the_last_swaps_fade_again_refits_it_from_the_model_before_it(
        tmp_path, monkeypatch):
    """After a swap that put a fade in, a departure suspecting the fade again is diagnosed from the
    model the swap's window was diagnosed from, with the running fade's clock at the window's start
    in the window's metadata (so the fade is fitted anew, continued, not patched by another effect);
    one suspecting something else, from the running model, with no clock."""
    from rtlift.blocks.actuator_fade import ActuatorFade
    from rtlift.core.records import read_record
    from rtlift.effects.actuator_fade import ON_TIME0_META
    from rtlift.model.modelfile import load_model, save_model

    monkeypatch.setattr(DiagnoseWorker, "_start", _idle)
    faded = load_model(MODEL)
    faded.input_stages = (*faded.input_stages, ActuatorFade(0.8, 0.7, FS_HZ))
    faded.__post_init__()
    faded_path = tmp_path / "faded.json"
    save_model(faded, faded_path)
    calls = []

    def diagnose(self, argv):
        run = read_record(argv[argv.index("--run") + 1])
        calls.append((argv[argv.index("--model") + 1], run.meta.get(ON_TIME0_META["on_time"])))
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True, exist_ok=True)
        shutil.copy(faded_path, out / "model_augmented.json")
        (out / "report.json").write_text(json.dumps({
            "effects": [{"name": "actuator_fade", "accepted": True, "kind": "effect"}],
            "baseline": {"records": {"w": {"rmse": 0.02}}}, "augmented": {"records": {"w": {"rmse": 0.01}}}}))
        return 0, ""

    monkeypatch.setattr(DiagnoseWorker, "run", diagnose)
    events = []
    loop = _Loop()
    ad = Adapter(loop, MODEL, tmp_path, events=events.append)
    _cut_window(ad)                                   # Cμ 0.02 on every row
    ad._thread.join(60)
    n = int((BEFORE_S + AFTER_S) * FS_HZ) + 1
    for i, cmu in ((n, 0.0), (n + 1, 0.02)):           # a burst onset: the swap
        ad.before_step(i, cmu)
        ad.after_step(i, cmu, 0.01, 0.1)
    assert events[-1]["event"] == "adaptation" and ad.model_path == str(tmp_path / "model_adapt_1.json")
    assert calls == [(str(MODEL), None)]
    assert ad.diagnosed_from("actuator_fade") == str(MODEL)
    assert ad.diagnosed_from("zero_drift") == ad.model_path and ad.diagnosed_from(None) == ad.model_path
    fade = next(s for s in loop.observer.model.input_stages if isinstance(s, ActuatorFade))
    start = n + 2
    ad.on_departure({"sample": start + 1, "t_s": start / FS_HZ, "test": "bias", "suspect": "actuator_fade"})
    rows = int(AFTER_S * FS_HZ) + 1
    fade.on_time = 30.0                               # the running fade's clock after the window's last row
    for i in range(start, start + rows):
        ad.after_step(i, 0.02, 0.01, 0.1)
    ad._thread.join(60)
    window = int((BEFORE_S + AFTER_S) * FS_HZ)
    assert calls[1][0] == str(MODEL)
    assert float(calls[1][1]) == pytest.approx(30.0 - (window - 1) / FS_HZ, abs=1e-9)   # row n had no burst
    ad.before_step(start + rows + 1, 0.0)
    ad.before_step(start + rows + 2, 0.02)
    assert events[-1]["event"] == "adaptation" and events[-1]["refit"] == "actuator_fade"
    assert ad.model_path == str(tmp_path / "model_adapt_2.json") and ad.diagnosed_from("actuator_fade") == str(MODEL)
    ad.close(0.0)

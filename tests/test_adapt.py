"""``rtlift control --adapt`` end to end over a real pseudo-terminal (issue 29): the loop tracks
steps on the simulated bench while an actuator fade the model is not told about sets in at
t = 20 s of tracking (to 70 %, on-time constant 2 s); the monitor raises a departure, another
process diagnoses the window, the augmented model is swapped in at a burst onset, and
``rtlift replay`` of the log makes the same swap at the same sample and sends the same commands
bit for bit. The same loop without the fade, beside it, raises nothing and swaps nothing.

What a loaded machine does to it: the diagnosis runs niced in another process, and on a machine
that gives it little CPU it can end after the 120 s run. The run's end then waits for it
(:data:`rtlift.app.adapt.END_WAIT_S`), so the summary still says what the window's diagnosis
accepted; the test checks that first (the fade accepted), then the swap within the run, and a
swap missed for the run's end fails with the diagnosis's own reason, not with "no swap"."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rtlift.app.cli import main
from rtlift.app.hil_tracking import BenchTracking, lowpass, reference_values

pytestmark = [pytest.mark.pty, pytest.mark.slow]

MODEL = str(Path(__file__).parent / "data" / "bench_model.json")
REFERENCE = "steps:0.06@0,0.12@12,0.08@24,0.14@36,0.06@48,0.12@60,0.09@72,0.13@84,0.07@96,0.11@108"
SECONDS = 120.0
"""The issue's run. At 100 s the swap (≈ 62–65 s of tracking) fell inside the scored last 40 s,
and one of two runs on a loaded machine failed the 1.3 × line (its numbers were not kept)."""
ONSET_TRACKING_S = 20.0
TARE_S = 2.0   # the observer (and the monitor's clock) starts after the 1 s settle, tracking 2 s later (tare)
FADE = f"actuator_fade:final_fraction=0.7,time_constant_s=2,onset_s={ONSET_TRACKING_S + 3.0:g}"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The two loops one after the other, not side by side: each a device and a 400 Hz host in real
    time, and the fade's a diagnosis beside them. Side by side on CI's two cores, with the computing
    workers beside them, the fade's commands came up to 180 ms late from its first tracking seconds
    (command latency p99 13 ms against 4 ms in a green run) and its loop ran another course: no test
    fired before the reference step at 26 s, and the fade was first named at 37 s, after that step's
    hold-off, where green runs name it at 26 s (CI of 7fe63ec, 2026-11-29; the same at 51be10f).
    120 s more of the real-time group."""
    tmp = tmp_path_factory.mktemp("adapt")
    cases = {"fade": (FADE,), "clean": ()}
    out = {}
    for name, effects in cases.items():
        extra = ("--adapt", str(tmp / f"{name}_adapt"), "--log", str(tmp / f"{name}.bin"))
        run = BenchTracking(MODEL, REFERENCE, True, SECONDS, str(tmp / f"{name}.json"), seed=21,
                            effects=effects, extra=extra).start()
        res = run.finish()
        t, truth, _ = run.traces()
        err = lowpass(truth) - lowpass(reference_values(REFERENCE, len(truth)))
        out[name] = {"result": res, "summary": run.summary, "stderr": run.stderr, "log": tmp / f"{name}.bin",
                     "rmse_last40": float(np.sqrt(np.mean(err[t >= SECONDS - 40.0] ** 2))), "tmp": tmp}
    return out


def test_the_fade_is_raised_and_the_loop_adapts_to_it(runs):
    s = runs["fade"]["summary"]
    onset = ONSET_TRACKING_S + TARE_S          # the onset on the monitor's clock: 22 s
    deps = s["departures"]
    assert deps and deps[0]["t_s"] > onset, deps                       # nothing before the onset
    # the issue: a departure naming the fade within 10 s of its onset (the hold test: the loop holds
    # its lift between reference steps, and the residual moves when the actuators fade)
    assert deps[0]["t_s"] <= onset + 10.0, deps
    assert deps[0]["suspect"] == "actuator_fade", deps
    # the first window's diagnosis accepts the fade (waited for at the run's end if it was still running)
    first = s["adaptations"][0] if s["adaptations"] else {}
    assert "actuator_fade" in (first.get("accepted") or []), s["adaptations"]
    # and it was swapped in within the run (else: its reason, e.g. the run ended before the swap)
    swaps = [a for a in s["adaptations"] if a.get("swapped")]
    assert swaps, [(a.get("accepted"), a.get("reason")) for a in s["adaptations"]]
    assert "actuator_fade" in swaps[0]["accepted"]
    assert swaps[0]["rmse_after"] < swaps[0]["rmse_before"]
    doc = json.loads(Path(swaps[0]["model_file"]).read_text())
    assert doc["provenance"]["adaptation"]["accepted"] == swaps[0]["accepted"]
    assert any(st["name"] == "actuator_fade" for st in doc["input_stages"])
    assert s["lost"] == 0
    assert "departure at t=" in runs["fade"]["stderr"] and "adaptation at t=" in runs["fade"]["stderr"]


def test_tracking_after_the_swap_is_as_good_as_without_the_fade(runs):
    assert runs["fade"]["rmse_last40"] <= 1.3 * runs["clean"]["rmse_last40"] + 1e-3, \
        (runs["fade"]["rmse_last40"], runs["clean"]["rmse_last40"])


def test_the_clean_loop_raises_nothing_and_swaps_nothing(runs):
    s = runs["clean"]["summary"]
    assert s["departures"] == []
    assert s["adaptations"] == []
    assert s["monitor"]["evaluations"] > 80


def test_replay_makes_the_same_swaps_and_sends_the_same_commands(runs, tmp_path):
    log = runs["fade"]["log"]
    out = tmp_path / "replay.json"
    assert main(["replay", str(log), "--model", MODEL, "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["commands"]["identical"] and r["commands"]["replayed"] == r["commands"]["logged"] > 100
    assert r["loop_events"]["identical"], r["loop_events"]
    live = [(a["index"], a["model_file"]) for a in runs["fade"]["summary"]["adaptations"] if a.get("swapped")]
    assert [(a["index"], a["model_file"]) for a in r["adaptations"] if a.get("swapped")] == live


def test_replay_says_so_when_the_events_do_not_match(runs, tmp_path):
    log = runs["fade"]["log"]
    events = Path(f"{log}.events.jsonl").read_text().splitlines()
    copy = tmp_path / "copy.bin"
    copy.write_bytes(log.read_bytes())
    Path(f"{copy}.commands.csv").write_text(Path(f"{log}.commands.csv").read_text())
    kept = [e for e in events if json.loads(e)["event"] != "adaptation"]   # as if no swap had happened
    Path(f"{copy}.events.jsonl").write_text("\n".join(kept) + "\n")
    proc = subprocess.run([sys.executable, "-m", "rtlift", "replay", str(copy), "--model", MODEL],
                          capture_output=True, text=True, env={**os.environ})
    assert proc.returncode == 1
    assert "differ" in proc.stderr or "DIFFERENT" in proc.stdout

"""Issue 27's closed-loop line, end to end over a real pseudo-terminal: ``rtlift control`` tracks
a slow sine on the simulated bench (a HIL plant) while an actuator fade the model is not told
about sets in (to 75 % over 0.4 s of burst on-time: most of it within the first ten seconds of
tracking); ``rtlift replay LOG --record`` turns the loop's own log into a record and
``rtlift diagnose --run`` (fitted on the first 60 %, judged on the rest) names the fade. The same
loop without the fade, run beside it, accepts nothing.

The model is the bench-identified ``tests/data/bench_model.json`` (the one ``rtlift control``'s
own end-to-end test drives); the fade is the demo's (:data:`rtlift.app.hil_tracking.FADE`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rtlift.app.cli import main
from rtlift.app.hil_tracking import FADE, BenchTracking
from rtlift.core.rate import FS_HZ
from rtlift.core.records import read_record

pytestmark = [pytest.mark.pty, pytest.mark.slow]

MODEL = Path(__file__).parent / "data" / "bench_model.json"
REFERENCE = "sine:mean=0.1,amp=0.05,hz=0.2"
SECONDS = 40
FS = int(FS_HZ)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same closed loop with the fade and without it, side by side; each log replayed as a
    record and diagnosed as one run."""
    tmp = tmp_path_factory.mktemp("closed_loop")
    started = {name: BenchTracking(str(MODEL), REFERENCE, True, SECONDS, str(tmp / f"{name}.json"), seed=5,
                                   effects=tuple(effects), log=str(tmp / f"{name}.bin")).start()
               for name, effects in (("fade", [FADE]), ("clean", []))}
    out = {}
    for name, run in started.items():
        run.finish()
        record = tmp / f"{name}_run.csv"
        run.record(str(record))
        assert main(["diagnose", "--model", str(MODEL), "--run", str(record), "--out", str(tmp / name)]) == 0
        out[name] = {"record": read_record(record), "report": json.loads((tmp / name / "report.json").read_text()),
                     "summary": json.loads((tmp / f"{name}.json").read_text())}
    return out


@pytest.fixture
def diagnosed(runs):
    return runs["fade"]


def test_the_loop_log_becomes_a_record_of_the_whole_observed_run(diagnosed):
    rec, s = diagnosed["record"], diagnosed["summary"]
    # the observer starts after the 1 s settle: tare (2 s) and tracking are in the record
    assert len(rec) == (2 + SECONDS) * FS
    assert rec.meta["loop"] == "control" and rec.meta["control_reference"] == REFERENCE
    assert rec.meta["lost"] == str(s["lost"]) == "0" and rec.meta["filled"] == "0"
    assert np.all(rec.cmu_envelope[:2 * FS] == 0)            # the actuator is off while the loop tares
    assert np.ptp(rec.cmu_envelope) > 0.01                     # then the controller moves the envelope


def test_the_fade_is_named_with_its_final_fraction(diagnosed):
    rep = diagnosed["report"]
    acc = [e for e in rep["effects"] if e["accepted"]]
    tried = {e["name"]: (e["kind"], e["accepted"], e["evidence"]) for e in rep["effects"]
             if e["accepted"] or e["name"] == "actuator_fade"}
    assert [(e["name"], e["kind"]) for e in acc] == [("actuator_fade", "effect")], tried
    assert acc[0]["params"]["final_fraction"] == pytest.approx(0.75, abs=0.05)
    # on the held-out 40 % of the run, the fade's error is mostly gone
    assert acc[0]["validation_rmse_after"] < 0.5 * acc[0]["validation_rmse_before"]
    assert rep["split"]["train_samples"] == [0, int(0.6 * len(diagnosed["record"]))]


def test_the_same_loop_without_the_fade_accepts_nothing(runs):
    rep = runs["clean"]["report"]
    assert [e["name"] for e in rep["effects"] if e["accepted"]] == []
    assert rep["augmented"]["records"] == rep["baseline"]["records"]

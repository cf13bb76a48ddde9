"""``rtlift diagnose --suspect`` and ``--adapt``'s use of it: between explanations that fit a record
alike, the effect another source of evidence names ranks first (rtlift.diagnose.lift, step 5).

The record is the window ``rtlift control --adapt`` cut after the fade of tests/test_adapt.py in a CI
run (tests/data/adapt_fade_window.csv: 26 s of a closed loop on the simulated bench, an actuator fade
to 70 % set in 2 s before it): a fade and a zero drift fit it alike, the window's own tests chose the
drift, and the run swapped in a drift. The live monitor had named the fade (its ``hold`` test)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rtlift.app.cli import main

DATA = Path(__file__).parent / "data"
MODEL = str(DATA / "bench_model.json")
WINDOW = str(DATA / "adapt_fade_window.csv")


def _diagnose(tmp_path, *extra: str) -> dict:
    out = tmp_path / "_".join(extra or ("plain",))
    assert main(["diagnose", "--model", MODEL, "--run", WINDOW, "--split", "0.6", "--out", str(out), "--quiet",
                 *extra]) == 0
    return json.loads((out / "report.json").read_text())


def test_the_suspect_decides_between_a_fade_and_a_drift_that_fit_the_window_alike(tmp_path, capsys):
    """Without a suspect the drift is chosen; with the monitor's suspect the fade; either way the
    two fit the held-out part within the 2 % band of each other (so nothing but the suspect moved),
    and the report's rule names the suspect."""
    plain, told = _diagnose(tmp_path), _diagnose(tmp_path, "--suspect", "actuator_fade")
    assert [e["name"] for e in plain["effects"] if e["accepted"]] == ["zero_drift"]
    assert [e["name"] for e in told["effects"] if e["accepted"]] == ["actuator_fade"]
    after = {e["name"]: e["validation_rmse_after"] for e in plain["effects"]}
    before = plain["effects"][0]["validation_rmse_before"]
    assert after["actuator_fade"] < 0.5 * before and after["zero_drift"] < 0.5 * before
    assert abs(after["actuator_fade"] / after["zero_drift"] - 1.0) < 0.02
    assert "the one with the suspect named beside the record (actuator_fade)" in told["selection"]["rule"]
    assert "suspect" not in plain["selection"]["rule"]
    # a suspect that loses by more than the band does not win: the same record told of a sensor resonance
    resonance = _diagnose(tmp_path, "--suspect", "sensor_resonance")
    assert [e["name"] for e in resonance["effects"] if e["accepted"]] == ["zero_drift"]


@pytest.mark.parametrize("name", ["fade", "ARX"])
def test_a_suspect_that_is_not_one_of_the_effects_is_one_line_and_exit_2(tmp_path, capsys, name):
    assert main(["diagnose", "--model", MODEL, "--run", WINDOW, "--out", str(tmp_path / "d"), "--suspect", name]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--suspect {name}: one of a lift model's effects" in err[0]


def test_adapt_passes_the_departure_s_suspect_to_the_window_s_diagnosis(tmp_path, monkeypatch):
    """The adapter's diagnosis command carries ``--suspect`` with the departure's suspect (an effect's
    name; none where the monitor named none)."""
    from rtlift.app.adapt import Adapter
    from rtlift.app.diagnose_worker import DiagnoseWorker
    from tests.test_adapt_end import _cut_window, _idle, _Loop

    argvs = []
    monkeypatch.setattr(DiagnoseWorker, "_start", _idle)
    monkeypatch.setattr(DiagnoseWorker, "run", lambda self, argv: (argvs.append(argv), (1, "stub\n"))[1])
    for suspect in ("actuator_fade", None):
        ad = Adapter(_Loop(), MODEL, tmp_path / str(suspect), events=lambda e: None)
        _cut_window(ad, suspect)
        ad.close()
    assert argvs[0][-2:] == ["--suspect", "actuator_fade"]
    assert "--suspect" not in argvs[1] and argvs[1][0] == "diagnose"

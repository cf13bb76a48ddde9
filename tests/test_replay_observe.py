"""``rtlift replay``: the log of a live ``rtlift observe`` run, replayed through the same
observer, gives the same estimates bit for bit (also across lost and corrupted frames, and
when paced in real time)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter
from hil_sim.experiments import daq_stream
from rtlift.app.cli import main
from tests.test_live_observe import estimate_rows, start_observe

FAULTS = FaultPlan(corrupt=0.01, drop=0.01, duplicate=0.01, garbage=0.005)


def live_run(make, model_file: Path, tmp: Path, seconds: float) -> tuple[Path, dict, list[str]]:
    dev = make(daq_stream("random", seed=11), faults=FAULTS, seed=5)
    with dev:
        proc = start_observe(dev, model_file, tmp, "--seconds", str(seconds))
        _, err = proc.communicate(timeout=60 + seconds)
    assert proc.returncode == 0, err
    log = tmp / ("frames.bin" if make is SerialDaq else "frames.asc")
    return log, json.loads((tmp / "summary.json").read_text()), estimate_rows(tmp / "estimates.csv")


@pytest.mark.pty
@pytest.mark.parametrize("make", [SerialDaq, SlcanAdapter], ids=["serial", "slcan"])
def test_replaying_a_live_log_reproduces_its_estimates_bit_for_bit(make, model_file, tmp_path, capsys):
    log, live, rows = live_run(make, model_file, tmp_path, 8.0)
    assert live["lost"] > 0 and live["crc_errors"] > 0 and live["samples_filled"] > 0
    out = tmp_path / "replayed.csv"
    assert main(["replay", str(log), "--model", str(model_file), "--out", str(out),
                 "--json", str(tmp_path / "replay.json")]) == 0
    replayed = estimate_rows(out)
    assert len(rows) == live["estimates"] == 3200
    assert replayed[:len(rows)] == rows                  # the CSV holds repr() floats: exact
    assert len(replayed) - len(rows) < 200               # frames read after the last estimate
    again = json.loads((tmp_path / "replay.json").read_text())
    for key in ("crc_errors", "lost", "duplicates", "resyncs", "events"):
        assert again[key] >= live[key]
    assert "rtlift replay" in capsys.readouterr().out


@pytest.mark.pty
def test_a_realtime_can_replay_takes_device_time_and_gives_the_same_estimates(model_file, tmp_path):
    log, live, rows = live_run(SlcanAdapter, model_file, tmp_path, 3.0)
    out = tmp_path / "replayed.csv"
    t0 = time.perf_counter()
    assert main(["replay", str(log), "--model", str(model_file), "--realtime", "--out", str(out)]) == 0
    elapsed = time.perf_counter() - t0
    assert elapsed >= 2.7           # paced on the device clock (how close: benchmarks/pacing.py)
    assert estimate_rows(out)[:len(rows)] == rows


def test_an_unknown_log_type_is_one_line_and_exit_2(model_file, tmp_path, capsys):
    bad = tmp_path / "frames.txt"
    bad.write_text("nothing")
    assert main(["replay", str(bad), "--model", str(model_file)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown log type" in err

"""``rtlift observe`` live on the bench emulators over real pseudo-terminals (serial DAQ and
python-can's slcan driver), and its exit paths."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from firmware_io.logs import read_log
from firmware_io.samples import COMMAND_KEYS
from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter
from hil_sim.experiments import daq_stream
from rtlift.app.cli import main
from rtlift.model.modelfile import save_model
from tests.test_observer_bench import bench_model

KEYS = ("received", "crc_errors", "lost", "resyncs", "events", "duplicates", "estimates",
        "latency_p50_ms", "latency_p99_ms")


def link_args(dev) -> list[str]:
    return ["--serial", dev.path] if isinstance(dev, SerialDaq) else ["--can", f"slcan:{dev.path}"]


def start_observe(dev, model_file: Path, tmp: Path, *extra: str) -> subprocess.Popen:
    """Launch ``rtlift observe`` and start the device once the link is open (so the tare
    sees the experiment's actuator-off start)."""
    log = tmp / ("frames.bin" if isinstance(dev, SerialDaq) else "frames.asc")
    cmd = [sys.executable, "-m", "rtlift", "observe", *link_args(dev), "--model", str(model_file),
           "--log", str(log), "--out", str(tmp / "estimates.csv"), "--json", str(tmp / "summary.json"), *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    assert "link open" in line, line + proc.stderr.read()
    dev.start()
    return proc


def estimate_rows(path: Path) -> list[str]:
    return [r for r in path.read_text().splitlines() if r and not r.startswith("#")][1:]


@pytest.fixture(scope="module")
def sixty_seconds(model_file, tmp_path_factory):
    """Sixty seconds of ``rtlift observe`` on a serial DAQ and on an SLCAN adapter, the two runs
    side by side (two devices, two processes: each link is its own; the suite waits one minute,
    not two)."""
    runs = {}
    for name, make in (("serial", SerialDaq), ("slcan", SlcanAdapter)):
        tmp = tmp_path_factory.mktemp(f"sixty_{name}")
        dev = make(daq_stream("random", seed=7))
        runs[name] = (dev, tmp, start_observe(dev, model_file, tmp, "--seconds", "60"))
    out = {}
    try:
        for name, (_dev, tmp, proc) in runs.items():
            stdout, stderr = proc.communicate(timeout=120)
            out[name] = (proc.returncode, stdout, stderr, tmp)
    finally:
        for dev, _, proc in runs.values():
            proc.kill()
            dev.stop()
    return out


@pytest.mark.pty
@pytest.mark.parametrize("name", ["serial", "slcan"])
def test_sixty_seconds_live_at_400_hz_lose_no_sample(sixty_seconds, name):
    code, out, err, tmp_path = sixty_seconds[name]
    assert code == 0, err
    s = json.loads((tmp_path / "summary.json").read_text())
    assert set(KEYS) <= set(s)
    assert s["lost"] == 0 and s["crc_errors"] == 0 and s["duplicates"] == 0
    assert s["samples_stepped"] == 24_000 and s["estimates"] == 24_000 and s["end"] == "completed"
    assert len(estimate_rows(tmp_path / "estimates.csv")) == 24_000
    assert 0 < s["latency_p50_ms"] <= s["latency_p99_ms"]   # its size: benchmarks/observer_loop.py
    assert 0.85 <= s["observer"]["nis_band_fraction"] <= 0.99
    assert "completed" in out and "lost 0" in out


@pytest.mark.pty
def test_spinning_on_the_port_changes_no_estimate_and_loses_nothing(model_file, tmp_path):
    """``--spin`` busy-polls the serial port between samples, ``--spin 0.5`` only from 0.5 ms
    before each sample is due: the same stream gives the same estimate rows, bit for bit, as the
    sleeping loop (the samples are the clock, not the host)."""
    rows = {}
    flags = {"sleep": (), "spin": ("--spin",), "spin_tail": ("--spin", "0.5")}
    for mode in flags:
        tmp = tmp_path / mode
        tmp.mkdir()
        with SerialDaq(daq_stream("random", seed=7)) as dev:
            proc = start_observe(dev, model_file, tmp, "--seconds", "8", *flags[mode])
            _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
        s = json.loads((tmp / "summary.json").read_text())
        assert s["lost"] == 0 and s["samples_stepped"] == 3200
        rows[mode] = [r.split(",") for r in estimate_rows(tmp / "estimates.csv")]
    cut = lambda table: [r[:3] + r[4:] for r in table]     # noqa: E731  (t_us, the device clock, aside)
    assert len(rows["spin"]) == 3200 and cut(rows["spin"]) == cut(rows["sleep"])
    assert cut(rows["spin_tail"]) == cut(rows["sleep"])


@pytest.mark.parametrize("window", ["0", "2.5", "x"])
def test_a_spin_window_outside_one_period_is_one_line_and_exit_2(model_file, capsys, window):
    with pytest.raises(SystemExit) as exc:
        main(["observe", "--serial", "/dev/null", "--model", str(model_file), "--spin", window])
    assert exc.value.code == 2
    assert capsys.readouterr().err.count("--spin: ") == 1


def test_spin_on_a_can_link_is_one_line_and_exit_2(model_file, capsys):
    assert main(["observe", "--can", "slcan:/dev/null", "--model", str(model_file), "--spin"]) == 2
    assert capsys.readouterr().err.count("rtlift: error: --spin is for a serial link") == 1


@pytest.mark.pty
@pytest.mark.parametrize("make", [SerialDaq, SlcanAdapter], ids=["serial", "slcan"])
def test_when_the_device_disappears_the_summary_has_the_exact_counters(make, model_file, tmp_path):
    dev = make(daq_stream("random", seed=8),
               faults=FaultPlan(disconnect_after_s=4.0, drop=0.01, start=900, stop=1500))
    with dev:
        proc = start_observe(dev, model_file, tmp_path)
        out, err = proc.communicate(timeout=60)
        delivered = dev.stats.samples_delivered
    assert proc.returncode == 1
    said = [line for line in err.splitlines() if "monitor thresholds:" not in line]   # that one: a line of its own
    assert len(said) == 1 and "disappeared" in said[0], err   # one line (after the "link open" line)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["end"] == "disconnected"
    assert delivered - 100 <= s["received"] <= delivered        # what was in flight at the unplug is gone
    assert s["lost"] == dev.stats.samples_lost > 0
    log = tmp_path / ("frames.bin" if make is SerialDaq else "frames.asc")
    decoded = read_log(log)
    assert sum(1 for _ in decoded) == s["received"]
    link_counters = {k: v for k, v in decoded.counters.as_dict().items() if k not in COMMAND_KEYS}
    assert {k: s[k] for k in link_counters} == link_counters  # observe's summary pins no command keys
    assert s["estimates"] == s["received"] + s["samples_filled"] == len(estimate_rows(tmp_path / "estimates.csv"))
    assert s["latency_p99_ms"] is not None


@pytest.mark.pty
@pytest.mark.parametrize("sig,code,end", [(signal.SIGTERM, 128 + signal.SIGTERM, "terminated"),
                                          (signal.SIGINT, 130, "interrupted")], ids=["SIGTERM", "Ctrl-C"])
def test_a_signal_ends_the_loop_with_everything_flushed(sig, code, end, model_file, tmp_path):
    dev = SerialDaq(daq_stream("random", seed=9))
    with dev:
        proc = start_observe(dev, model_file, tmp_path)
        time.sleep(3.0)
        os.kill(proc.pid, sig)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == code, err
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["end"] == end and s["received"] > 600
    assert s["estimates"] == len(estimate_rows(tmp_path / "estimates.csv"))
    assert (tmp_path / "frames.bin").stat().st_size >= 41 * s["received"]


def test_a_missing_serial_port_is_one_line_and_exit_2(model_file, tmp_path, capsys):
    code = main(["observe", "--serial", str(tmp_path / "ttyNOPE"), "--model", str(model_file),
                 "--json", str(tmp_path / "s.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "no such device" in err


def test_an_unknown_can_interface_is_one_line_and_exit_2(model_file, capsys):
    code = main(["observe", "--can", "warpdrive:0", "--model", str(model_file)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "unknown CAN interface 'warpdrive'" in err


def test_a_model_without_observer_settings_is_one_line_and_exit_2(tmp_path, capsys):
    model = bench_model(("random",))
    model.observer_config = {}
    save_model(model, tmp_path / "bare.json")
    code = main(["observe", "--serial", "/dev/null", "--model", str(tmp_path / "bare.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "no observer settings" in err

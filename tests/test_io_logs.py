"""Logs for replay: what a live link logs, ``read_log`` decodes into the same samples with the
same counters; logs are complete after SIGTERM or Ctrl-C; record CSVs follow INTERFACES.md."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from firmware_io import LogError, RecordWriter, open_link, read_log
from firmware_io.logs import graceful_exit
from hil_sim.devices import FaultPlan, SerialDaq, SlcanAdapter, synthetic_stream
from rtlift.core.records import read_record

REPO = Path(__file__).resolve().parents[1]


def fields(s):
    return (s.seq, s.t_us, s.volt_cv, s.envelope_cv, s.ft, s.status)


def live_then_replay(dev, config, log, within_s=60.0):
    """Stream until the device finished, then read the log back. A device that never finishes
    fails the test after ``within_s`` (seen once under heavy load: the loop spun on a link that
    returned nothing while the device waited), never hangs the suite."""
    with dev, open_link({**config, "log": str(log)}) as link:
        dev.start()
        live = []
        give_up = time.monotonic() + within_s
        while True:
            s = link.recv(0.5)
            if s is None and dev.finished.is_set():
                break
            if s is not None:
                live.append(s)
            assert time.monotonic() < give_up, (f"device not finished after {within_s} s: "
                                                f"{len(live)} samples, {link.counters.as_dict()}, {dev.stats}")
        live_counters = link.counters.as_dict()
    replay = read_log(log)
    return live, live_counters, list(replay), replay.counters.as_dict()


@pytest.mark.pty
def test_a_raw_serial_capture_replays_to_the_same_samples_and_counters(tmp_path):
    plan = FaultPlan(corrupt=0.02, drop=0.02, duplicate=0.02, garbage=0.02)
    dev = SerialDaq(synthetic_stream(1), faults=plan, seed=3, max_samples=600)
    dev.send_event("burst driver warm")
    live, live_c, replay, replay_c = live_then_replay(dev, {"kind": "serial", "port": dev.path},
                                                      tmp_path / "run.bin")
    assert live_c["crc_errors"] > 0 and live_c["events"] == 1
    assert replay_c == live_c and [fields(s) for s in replay] == [fields(s) for s in live]


@pytest.mark.pty
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_a_can_log_replays_to_the_same_samples_and_counters(tmp_path, suffix):
    plan = FaultPlan(corrupt=0.01, drop=0.01, duplicate=0.01)
    dev = SlcanAdapter(synthetic_stream(2), faults=plan, seed=4, max_samples=600)
    config = {"kind": "can", "interface": "slcan", "channel": dev.path}
    live, live_c, replay, replay_c = live_then_replay(dev, config, tmp_path / f"run{suffix}")
    assert live_c["crc_errors"] > 0 and live_c["received"] > 500
    assert replay_c == live_c and [fields(s) for s in replay] == [fields(s) for s in live]


def test_log_types_are_chosen_by_extension_and_must_suit_the_link(tmp_path):
    with pytest.raises(LogError):
        read_log(tmp_path / "run.txt")
    with pytest.raises(LogError):
        read_log(tmp_path / "missing.bin")
    with pytest.raises(LogError):
        open_link({"kind": "serial", "port": "loop://", "log": str(tmp_path / "run.asc")})


def test_record_writer_writes_a_record_file_that_reads_back(tmp_path):
    path = tmp_path / "live.csv"
    with RecordWriter(path, {"experiment": "live", "fs_hz": 400}, ("seq",)) as w:
        for k in range(5):
            w.write(k / 400, 0.001 * k, 0.002, 0.01 * k, k)
    rec = read_record(path)
    assert rec.meta == {"experiment": "live", "fs_hz": "400"}
    assert rec.dcl.tolist() == [0.0, 0.01, 0.02, 0.03, 0.04] and rec.extra["seq"].tolist() == [0, 1, 2, 3, 4]


def test_graceful_exit_turns_sigterm_into_system_exit_and_restores_the_handler():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(SystemExit) as info, graceful_exit():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # interrupted by the handler
    assert info.value.code == 128 + signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is before


CHILD = textwrap.dedent("""
    import json, sys
    from firmware_io import open_link
    from firmware_io.logs import graceful_exit
    from hil_sim.devices import SerialDaq, SlcanAdapter, synthetic_stream

    kind, log = sys.argv[1], sys.argv[2]
    dev = (SerialDaq if kind == "serial" else SlcanAdapter)(synthetic_stream(5)).start()
    config = ({"kind": "serial", "port": dev.path} if kind == "serial"
              else {"kind": "can", "interface": "slcan", "channel": dev.path})
    link = None
    last = None
    code = 0
    ready = False
    try:
        with graceful_exit(), open_link({**config, "log": log}) as link:
            for s in link:
                last = s.seq
                if not ready and link.counters.received >= 200:   # the count may pass 200 between two reads
                    print("ready", flush=True)
                    ready = True
    except KeyboardInterrupt:
        code = 130
    except SystemExit as exc:
        code = exc.code
    finally:
        print(json.dumps({"received": link.counters.received, "last_seq": last}), flush=True)
        dev.stop()
    sys.exit(code)
""")


@pytest.mark.pty
@pytest.mark.parametrize("kind,suffix,sig", [("serial", ".bin", signal.SIGTERM), ("can", ".blf", signal.SIGINT),
                                             ("can", ".asc", signal.SIGTERM)])
def test_a_log_in_progress_is_complete_after_sigterm_or_ctrl_c(tmp_path, kind, suffix, sig):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    log = tmp_path / f"run{suffix}"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    child = subprocess.Popen([sys.executable, str(script), kind, str(log)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env)
    try:
        # a child that never gets there fails the test instead of hanging it
        assert select.select([child.stdout], [], [], 60.0)[0], "the child received no 200 samples in 60 s"
        assert child.stdout.readline().strip() == "ready"
        child.send_signal(sig)
        out, err = child.communicate(timeout=20)
    finally:
        child.kill()
    assert child.returncode == (143 if sig == signal.SIGTERM else 130), err
    assert "Traceback" not in err
    summary = json.loads(out.strip().splitlines()[-1])
    samples = list(read_log(log))
    # every sample the link delivered is in the log, in order (the last read may add a few)
    assert summary["received"] >= 200
    assert summary["received"] <= len(samples) <= summary["received"] + 3
    assert samples[summary["received"] - 1].seq == summary["last_seq"]


def test_a_command_log_reads_back_and_a_broken_one_is_one_line(tmp_path):
    from firmware_io.logs import CommandLog, LoggedCommand, commands_path, read_command_log

    frames = tmp_path / "run.bin"
    assert read_command_log(frames) is None                     # no commands beside this log
    sent = [LoggedCommand(400, 1, 0, 0, True, 0), LoggedCommand(1251, 2, 317, 0, True, 0),
            LoggedCommand(5200, 3, 0, 0, False, 0)]
    with CommandLog(commands_path(frames), {"reference": "steps:0.1@0", "feedback": "on"}) as log:
        for k, c in enumerate(sent):
            log.write(0.01 * k, c)
    meta, rows = read_command_log(frames)
    assert meta == {"reference": "steps:0.1@0", "feedback": "on"} and rows == sent
    path = commands_path(frames)
    path.write_text(path.read_text().replace("1251,2,317", "1251,2,3x7"))
    with pytest.raises(LogError, match=r"run\.bin\.commands\.csv:\d+: bad command row") as exc:
        read_command_log(frames)
    assert "\n" not in str(exc.value)
    path.write_text("t,u,y\n1,2,3\n")
    with pytest.raises(LogError, match="not a command log"):
        read_command_log(frames)

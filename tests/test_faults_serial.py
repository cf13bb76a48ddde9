"""Fault matrix, serial link: a raw capture with one kind of fault injected at known places is
replayed through ``rtlift replay`` (the same decoder, counters and observer loop as
``rtlift observe``). Every row: exit 0, no traceback, counters exact (sent = received +
lost, invalid packets and duplicates counted exactly), one estimate row per sent sample."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_io.serial_codec import SEQ_MODULUS
from hil_sim.devices.serial_daq import cobs_data_positions, invalid_chunks
from rtlift.core.rate import FS_HZ
from rtlift.observer import FLAG_MISSING, FLAG_REJECTED
from tests.test_faults_support import counters, rtlift, serial_frame, wire, write_calibration, write_model

N = 2000


@pytest.fixture
def replay(tmp_path, capsys):
    """Replay a list of wire chunks (bytes) as a raw capture: the in-process ``rtlift`` run."""
    model = write_model(tmp_path / "model.json")
    cal = write_calibration(tmp_path / "cal.toml")

    def run(chunks: list[bytes]):
        log = tmp_path / "run.bin"
        log.write_bytes(b"\x00" + b"".join(chunks))
        return rtlift(capsys, "replay", str(log), "--model", str(model), "--calibration", str(cal),
                      summary=tmp_path / "summary.json", out=tmp_path / "estimates.csv")

    return run


def clean(n: int = N, first_seq: int = 0) -> list[bytes]:
    return [serial_frame((first_seq + i) % SEQ_MODULUS, s) for i, s in enumerate(wire(n))]


def every(k: int, start: int = 100, stop: int = N - 100) -> list[int]:
    return list(range(start, stop, k))


def assert_clean_exit(run) -> None:
    assert run.code == 0 and not run.traceback and not any("error" in line for line in run.err), run.err


def test_corrupted_bytes(replay, record_property):
    """A changed byte invalidates exactly its packet (CRC); a byte turned into 0x00 splits it
    into two invalid packets. Only the hit samples are lost; the estimate rows stay complete."""
    frames = clean()
    rng = np.random.default_rng(1)
    changed = every(61)
    zeroed = [i + 30 for i in changed[::2]]  # apart from each other: each hit is its own resync
    for i in changed:
        pos = int(rng.choice(cobs_data_positions(frames[i])))
        frames[i] = frames[i][:pos] + bytes(((frames[i][pos] % 255) + 1,)) + frames[i][pos + 1:]
    for i in zeroed:
        mid = len(frames[i]) // 2
        frames[i] = frames[i][:mid] + b"\x00" + frames[i][mid + 1:]
    run = replay(frames)
    assert_clean_exit(run)
    hit = len(changed) + len(zeroed)
    assert counters(run.summary) == {"received": N - hit, "lost": hit, "crc_errors": len(changed) + 2 * len(zeroed),
                                     "duplicates": 0, "resyncs": hit}
    assert len(run.rows) == N and run.summary["samples_filled"] == hit
    record_property("measured", f"{hit} packets hit ({len(changed)} bytes changed, {len(zeroed)} zeroed): "
                                f"crc_errors {run.summary['crc_errors']}, lost {run.summary['lost']}, "
                                f"received {run.summary['received']}/{N}, {len(run.rows)} estimate rows")


def test_garbage_bursts(replay, record_property):
    """Random bursts between packets (and one 5000-byte run with no delimiter) are invalid
    packets and resyncs; no sample is lost."""
    frames = clean()
    rng = np.random.default_rng(2)
    expect_invalid = expect_runs = 0
    for i in every(53):
        junk = bytes(rng.integers(0, 256, int(rng.integers(1, 64))).tolist()) + b"\x00"
        frames[i] = junk + frames[i]
        expect_invalid += invalid_chunks(junk)
        expect_runs += invalid_chunks(junk) > 0
    long_run = bytes(rng.integers(1, 256, 5000).tolist()) + b"\x00"
    frames[N // 2] = long_run + frames[N // 2]
    run = replay(frames)
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N, "lost": 0, "crc_errors": expect_invalid + 1, "duplicates": 0,
                                     "resyncs": expect_runs + 1}
    assert len(run.rows) == N
    record_property("measured", f"{expect_runs + 1} bursts: crc_errors {run.summary['crc_errors']} "
                                f"(= invalid chunks injected), resyncs {run.summary['resyncs']}, lost 0, "
                                f"received {N}/{N}")


def test_truncated_frames(replay, record_property):
    """A packet cut short loses its tail and its delimiter: the stub and the next packet are
    one invalid packet, so both samples are lost, and nothing else."""
    frames = clean()
    rng = np.random.default_rng(3)
    cut = every(89)
    for i in cut:
        frames[i] = frames[i][:int(rng.integers(1, len(frames[i]) - 1))]
    run = replay(frames)
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N - 2 * len(cut), "lost": 2 * len(cut), "crc_errors": len(cut),
                                     "duplicates": 0, "resyncs": len(cut)}
    assert len(run.rows) == N
    record_property("measured", f"{len(cut)} truncated: crc_errors {run.summary['crc_errors']}, "
                                f"lost {run.summary['lost']} (stub + next), {len(run.rows)} estimate rows")


def test_dropped_frames(replay, record_property):
    """Dropped packets (single, and a run of 25) are lost, filled by predict-only steps."""
    frames = clean()
    dropped = set(every(71)) | set(range(1000, 1025))
    run = replay([f for i, f in enumerate(frames) if i not in dropped])
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N - len(dropped), "lost": len(dropped), "crc_errors": 0,
                                     "duplicates": 0, "resyncs": 0}
    flags = [int(r["flags"]) for r in run.rows]
    assert len(flags) == N and all(flags[i] & FLAG_MISSING for i in dropped)
    record_property("measured", f"{len(dropped)} dropped: lost {run.summary['lost']}, "
                                f"filled {run.summary['samples_filled']} predict-only rows, {len(flags)} rows")


def test_duplicated_frames(replay, record_property):
    """Repeated packets are counted as duplicates and dropped: no extra estimate, no loss."""
    frames = clean()
    twice, thrice = every(67), every(151, start=120)
    for i in twice:
        frames[i] *= 2
    for i in thrice:
        frames[i] *= 3
    run = replay(frames)
    assert_clean_exit(run)
    dup = len(twice) + 2 * len(thrice)
    assert counters(run.summary) == {"received": N, "lost": 0, "crc_errors": 0, "duplicates": dup, "resyncs": 0}
    assert [int(r["seq"]) for r in run.rows] == list(range(N))
    record_property("measured", f"{dup} extra copies: duplicates {run.summary['duplicates']}, received {N}/{N}, "
                                f"{len(run.rows)} rows in seq order")


def test_out_of_order_frames(replay, record_property):
    """A packet arriving after a newer one is late: the newer one counts it lost, the late
    copy is dropped as a duplicate — never a 65 534-sample 'loss' across the u16 seq."""
    frames = clean()
    swapped = every(101)
    for i in swapped:
        frames[i], frames[i + 1] = frames[i + 1], frames[i]
    frames[1500:1504] = [frames[1501], frames[1502], frames[1503], frames[1500]]  # one packet 3 places late
    late = len(swapped) + 1
    run = replay(frames)
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N - late, "lost": late, "crc_errors": 0, "duplicates": late,
                                     "resyncs": 0}
    assert [int(r["seq"]) for r in run.rows] == list(range(N))
    record_property("measured", f"{late} late packets: lost {run.summary['lost']}, duplicates "
                                f"{run.summary['duplicates']}, received {run.summary['received']}, rows in seq order")


def test_wrapped_serial_seq_and_device_clock(replay, record_property):
    """The u16 seq and the u32 µs device clock both wrap inside the run: nothing is lost and
    the estimate time (from seq) runs on uniformly."""
    first_seq, first_t = SEQ_MODULUS - N // 2, 2**32 - 2500 * (N // 3)
    frames = [serial_frame((first_seq + i) % SEQ_MODULUS, s, (first_t + 2500 * i) % 2**32)
              for i, s in enumerate(wire(N))]
    run = replay(frames)
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N, "lost": 0, "crc_errors": 0, "duplicates": 0, "resyncs": 0}
    t = np.array([float(r["t"]) for r in run.rows])
    seq = [int(r["seq"]) for r in run.rows]
    t_us = [int(r["t_us"]) for r in run.rows]
    assert len(t) == N and np.allclose(np.diff(t), 1 / int(FS_HZ), rtol=0, atol=1e-12)
    assert seq[N // 2] == 0 and t_us[N // 3] == 0  # both counters did wrap
    record_property("measured", f"seq {seq[0]}→{seq[-1]}, t_us {t_us[0]}→{t_us[-1]}: lost 0, {N} rows, "
                                "t steps uniform 2.5 ms")


def test_sensor_fault_and_saturation_flags(replay, record_property):
    """Samples flagged 'sensor fault' or 'ADC saturated' give no ΔCL: predict-only steps,
    counted as missing by the observer, marked in the estimate rows."""
    samples = wire(N)
    fault, saturated = every(41), list(range(1200, 1260))
    for i in fault:
        samples[i].status |= 0x04
    for i in saturated:
        samples[i].status |= 0x02
    run = replay([serial_frame(i, s) for i, s in enumerate(samples)])
    assert_clean_exit(run)
    flagged = set(fault) | set(saturated)
    assert run.summary["received"] == N and run.summary["observer"]["missing"] == len(flagged)
    missing = {i for i, r in enumerate(run.rows) if int(r["flags"]) & FLAG_MISSING}
    assert missing == flagged and all(run.rows[i]["dcl"] == "" for i in flagged)
    assert all(math.isfinite(float(r["dcl_hat"])) for r in run.rows)
    record_property("measured", f"{len(flagged)} flagged samples: observer missing "
                                f"{run.summary['observer']['missing']}, exactly those rows predict-only")


def test_absurd_counts(replay, record_property):
    """Forces at the i32 limits (±2147 N on a ±35 N transducer) are gated out by the χ² test
    (predict-only, counted as rejected): the estimate neither jumps nor turns non-finite."""
    samples = wire(N)
    absurd = every(173)
    for k, i in enumerate(absurd):
        lim = 2**31 - 1 if k % 2 else -(2**31)
        samples[i].ft = (lim, lim, lim, lim, lim, lim)
    run = replay([serial_frame(i, s) for i, s in enumerate(samples)])
    assert_clean_exit(run)
    dcl_hat = np.array([float(r["dcl_hat"]) for r in run.rows])
    flags = [int(r["flags"]) for r in run.rows]
    assert np.all(np.isfinite(dcl_hat))
    assert all(flags[i] & FLAG_REJECTED for i in absurd)
    assert run.summary["observer"]["rejected"] >= len(absurd)
    jump = max(abs(dcl_hat[i] - dcl_hat[i - 1]) for i in absurd)
    typical = np.percentile(np.abs(np.diff(dcl_hat)), 99.9)
    assert jump <= typical
    record_property("measured", f"{len(absurd)} absurd samples: all gated (flag rejected), observer rejected "
                                f"{run.summary['observer']['rejected']}, largest step at them {jump:.3g} "
                                f"<= p99.9 step {typical:.3g}")

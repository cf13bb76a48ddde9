"""Fault matrix, CAN bus: a python-can log (ASC) of the three frames per sample, with one
kind of fault at known places, replayed through ``rtlift replay`` (the same assembler and
observer loop as ``rtlift observe --can``). Every row: exit 0, no traceback, counters exact,
one estimate row per sent sample."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_io.can_codec import SEQ_MODULUS
from rtlift.core.rate import FS_HZ
from tests.test_faults_support import (
    can_frames,
    counters,
    rtlift,
    wire,
    write_calibration,
    write_can_log,
    write_model,
)

N = 2000


@pytest.fixture
def replay(tmp_path, capsys):
    model = write_model(tmp_path / "model.json")
    cal = write_calibration(tmp_path / "cal.toml")

    def run(frames: list[tuple[int, bytes]]):
        log = write_can_log(tmp_path / "run.asc", frames)
        return rtlift(capsys, "replay", str(log), "--model", str(model), "--calibration", str(cal),
                      summary=tmp_path / "summary.json", out=tmp_path / "estimates.csv")

    return run


def samples(n: int = N) -> list[list[tuple[int, bytes]]]:
    """Per sample, its three frames."""
    return [can_frames(i % SEQ_MODULUS, s) for i, s in enumerate(wire(n, "can"))]


def flat(per_sample: list[list[tuple[int, bytes]]]) -> list[tuple[int, bytes]]:
    return [f for frames in per_sample for f in frames]


def assert_clean_exit(run) -> None:
    assert run.code == 0 and not run.traceback and not any("error" in line for line in run.err), run.err


def test_incomplete_can_samples(replay, record_property):
    """A sample missing one of its three frames, or with a frame cut short (wrong DLC), is
    lost when the next sample completes; the short frame is counted invalid."""
    per = samples()
    missing, short = list(range(100, N - 100, 83)), list(range(140, N - 100, 211))
    for k, i in enumerate(missing):
        del per[i][k % 3]
    for k, i in enumerate(short):
        fid, data = per[i][k % 3]
        per[i][k % 3] = (fid, data[:4])
    run = replay(flat(per))
    assert_clean_exit(run)
    lost = len(missing) + len(short)
    assert counters(run.summary) == {"received": N - lost, "lost": lost, "crc_errors": len(short), "duplicates": 0,
                                     "resyncs": 0}
    assert len(run.rows) == N
    record_property("measured", f"{len(missing)} samples missing a frame, {len(short)} with a short frame: "
                                f"lost {run.summary['lost']}, crc_errors {run.summary['crc_errors']}, "
                                f"{len(run.rows)} rows")


def test_out_of_order_can_frames(replay, record_property):
    """Frames of one sample in any order still make the sample; a frame that comes after the
    next sample completed is late: that sample is lost and the frame dropped as a duplicate."""
    per = samples()
    rng = np.random.default_rng(4)
    for frames in per:
        rng.shuffle(frames)
    late = list(range(150, N - 100, 97))
    for i in late:
        per[i + 1].append(per[i].pop())  # the last frame of sample i arrives after sample i+1's
    run = replay(flat(per))
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N - len(late), "lost": len(late), "crc_errors": 0,
                                     "duplicates": len(late), "resyncs": 0}
    assert [int(r["seq"]) for r in run.rows] == [i % SEQ_MODULUS for i in range(N)]
    record_property("measured", f"all frames shuffled within their sample, {len(late)} late by one sample: "
                                f"lost {run.summary['lost']}, duplicates {run.summary['duplicates']}, "
                                f"received {run.summary['received']}")


def test_wrapped_can_seq_and_device_clock(replay, record_property):
    """The u8 seq wraps every 256 samples and the 10 µs device clock every 655 360 µs: over
    5 s nothing is lost and the estimate time (from seq) runs on uniformly."""
    per = [can_frames(i % SEQ_MODULUS, s, (i * 250) % 65536) for i, s in enumerate(wire(N, "can"))]
    run = replay(flat(per))
    assert_clean_exit(run)
    assert counters(run.summary) == {"received": N, "lost": 0, "crc_errors": 0, "duplicates": 0, "resyncs": 0}
    t = np.array([float(r["t"]) for r in run.rows])
    t_us = np.array([int(r["t_us"]) for r in run.rows])
    wraps_seq, wraps_clock = (N - 1) // SEQ_MODULUS, int(np.sum(np.diff(t_us) < 0))
    assert len(t) == N and np.allclose(np.diff(t), 1 / int(FS_HZ), rtol=0, atol=1e-12)
    assert wraps_seq == 7 and wraps_clock == 7
    record_property("measured", f"{wraps_seq} seq wraps, {wraps_clock} clock wraps in {N} samples: lost 0, "
                                "t steps uniform 2.5 ms")

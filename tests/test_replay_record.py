"""``rtlift replay LOG --model M --record F.csv``: a loop's log as a record file.

A serial capture and a CAN log built frame by frame (5 s at 400 Hz; samples lost on the link,
one flagged by the device): the record is uniform on the device's sample counter, its Cμ,
envelope and ΔCL are the very values the replayed observer loop was fed (``--out``'s
``dcl``, bit for bit), the tare window's ΔCL uses the tare the loop found, short gaps are
filled and marked, and a gap too long to fill is one line and exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from firmware_io.calibration import Calibration
from firmware_io.samples import STATUS_ADC_SATURATED
from rtlift.app.log_record import MAX_GAP_SAMPLES
from rtlift.core.rate import FS_HZ
from rtlift.core.records import read_record
from tests.test_faults_support import (
    can_frames,
    read_estimates,
    serial_frame,
    wire,
    write_can_log,
    write_model,
)

FS = int(FS_HZ)
N = 2000
LOST = (1000, 1001, 1002)
FLAGGED = 1500
TARE = int(Calibration().tare_seconds * FS)


def _samples(n: int, lost: tuple[int, ...], flagged: int | None, kind: str):
    out = []
    for seq, s in enumerate(wire(n, kind, seed=3)):
        if seq in lost:
            continue
        if seq == flagged:
            s.status |= STATUS_ADC_SATURATED
        out.append((seq, s))
    return out


def serial_log(path, n=N, lost=LOST, flagged=FLAGGED):
    path.write_bytes(b"".join(serial_frame(seq, s) for seq, s in _samples(n, lost, flagged, "serial")))
    return path


def can_log(path, n=N, lost=LOST, flagged=FLAGGED):
    return write_can_log(path, [f for seq, s in _samples(n, lost, flagged, "can") for f in can_frames(seq % 256, s)])


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return write_model(tmp_path_factory.mktemp("m") / "model.json")


@pytest.fixture(params=["serial", "can"])
def replayed(request, model, tmp_path, capsys):
    from rtlift.app.cli import main

    log = serial_log(tmp_path / "run.bin") if request.param == "serial" else can_log(tmp_path / "run.asc")
    est, rec = tmp_path / "est.csv", tmp_path / "run_record.csv"
    assert main(["replay", str(log), "--model", str(model), "--out", str(est), "--record", str(rec)]) == 0
    assert "record" in capsys.readouterr().out
    return read_record(rec), read_estimates(est), request.param


def test_the_record_is_uniform_on_the_device_counter_with_the_gaps_marked(replayed):
    rec, rows, _ = replayed
    assert len(rec) == N == len(rows)
    np.testing.assert_array_equal(rec.t, np.arange(N) / FS)
    assert rec.fs_hz == FS
    assert np.flatnonzero(rec.extra["filled"]).tolist() == [*LOST, FLAGGED]
    assert np.flatnonzero(rec.extra["flagged"]).tolist() == [FLAGGED]
    assert rec.meta["filled"] == "4" and rec.meta["gaps"] == "2" and rec.meta["lost"] == "3"
    assert rec.meta["loop"] == "observe" and rec.meta["source_log"].endswith(("run.bin", "run.asc"))


def test_the_inputs_and_the_measured_dcl_are_what_the_loop_was_fed_bit_for_bit(replayed):
    rec, rows, _ = replayed
    for col in ("cmu", "cmu_envelope"):          # held through a gap, as the loop holds them
        assert getattr(rec, col).tolist() == [float(r[col]) for r in rows]
    measured = [(i, float(r["dcl"])) for i, r in enumerate(rows) if r["dcl"]]
    assert len(measured) == N - TARE - 4
    assert all(rec.dcl[i] == d for i, d in measured)


def test_the_tare_window_has_the_tare_the_loop_found(replayed, tmp_path):
    """Samples converted while taring get CL − tare: CL from the forces through the calibration
    (its vectorised form, another code path than the loop's), the tare the mean CL of the window's
    unflagged samples with the actuator off, so their ΔCL averages zero."""
    from firmware_io.logs import read_log

    rec, rows, kind = replayed
    assert not any(r["dcl"] for r in rows[:TARE])
    log = Path(rec.meta["source_log"])
    samples = list(read_log(log))
    cal = Calibration()
    cl = np.asarray(cal.cl_from_ft(np.array([s.ft for s in samples[:TARE]])))
    tare = float(rec.meta["tare_cl"])
    np.testing.assert_allclose(rec.dcl[:TARE], cl - tare, rtol=0, atol=1e-12)
    off = np.array([s.volt_cv == 0 for s in samples[:TARE]])
    assert off.sum() > 10 and abs(np.mean(rec.dcl[:TARE][off])) < 1e-12


def test_a_gap_is_filled_by_linear_interpolation(replayed):
    rec, _, _ = replayed
    a, b = LOST[0] - 1, LOST[-1] + 1
    want = np.interp(LOST, [a, b], rec.dcl[[a, b]])
    np.testing.assert_allclose(rec.dcl[list(LOST)], want, rtol=0, atol=1e-15)
    assert rec.dcl[FLAGGED] == pytest.approx(0.5 * (rec.dcl[FLAGGED - 1] + rec.dcl[FLAGGED + 1]), abs=1e-15)


@pytest.mark.parametrize("kind", ["serial", "can"])
def test_a_gap_too_long_to_fill_is_one_line_and_exit_2(kind, model, tmp_path, capsys):
    from rtlift.app.cli import main

    lost = tuple(range(1200, 1200 + MAX_GAP_SAMPLES + 1))
    log = serial_log(tmp_path / "run.bin", lost=lost) if kind == "serial" else can_log(tmp_path / "run.asc", lost=lost)
    assert main(["replay", str(log), "--model", str(model), "--record", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"the longest gap {MAX_GAP_SAMPLES + 1} samples at t = 3.000 s" in err
    assert not (tmp_path / "r.csv").exists()


def test_a_log_that_ends_before_the_tare_is_one_line_and_exit_2(model, tmp_path, capsys):
    from rtlift.app.cli import main

    log = serial_log(tmp_path / "run.bin", n=TARE // 2, lost=(), flagged=None)
    assert main(["replay", str(log), "--model", str(model), "--record", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "ends before the tare" in err


def test_the_estimate_file_carries_the_model_rate_not_a_fixed_400(tmp_path):
    from rtlift.app.cli import main
    from rtlift.model.modelfile import save_model
    from testkit.synthetic import make_model
    from tests.test_faults_support import OBSERVER

    model = tmp_path / "model_200hz.json"
    save_model(make_model(np.random.default_rng(1), fs_hz=200.0), model, observer=dict(OBSERVER))
    log = serial_log(tmp_path / "run.bin", n=1000, lost=(), flagged=None)
    est = tmp_path / "est.csv"
    assert main(["replay", str(log), "--model", str(model), "--out", str(est)]) == 0
    meta = [line for line in est.read_text().splitlines() if line.startswith("#")]
    assert "# fs_hz: 200" in meta
    rows = read_estimates(est)
    assert float(rows[-1]["t"]) - float(rows[0]["t"]) == pytest.approx((len(rows) - 1) / 200.0)

"""Helpers of the fault matrix (tests/test_faults_*.py): a model file with observer settings,
clean wire frames from the bench stand-in, and the ``rtlift`` command line run in-process.

No tests here; each matrix row is one test in the other ``test_faults_*`` files, named after
the row, and records what it measured with ``record_property("measured", ...)`` for
``benchmarks/fault_matrix.py``.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from firmware_io.calibration import Calibration
from firmware_io.can_codec import encode_sample_frames
from firmware_io.serial_codec import encode_sample
from hil_sim.devices import synthetic_stream
from hil_sim.devices.source import can_wire, serial_wire, wire_samples
from rtlift.app.cli import main
from rtlift.model.modelfile import save_model
from testkit.synthetic import make_model

SENSOR_NOISE_N = 0.02
"""Force noise of ``synthetic_stream`` (N); R of the observer follows from it."""
OBSERVER = {"R": (SENSOR_NOISE_N / Calibration().q_area) ** 2, "q_x": 1e-8, "q_bias": 1e-9,
            "p0_bias": 1e-3}


def write_model(path: Path, seed: int = 1) -> Path:
    """A small stable hybrid model with observer settings (Q, R) at ``path``."""
    save_model(make_model(np.random.default_rng(seed)), path, observer=dict(OBSERVER))
    return path


def write_calibration(path: Path) -> Path:
    """The default calibration with a stored tare, so no sample is spent on taring."""
    cal = Calibration()
    tare = float(cal.cl_from_ft(np.array([-0.5, 0.0, 2.0, 0.0, 0.01, 0.0])))  # synthetic_stream at rest
    path.write_text(f"tare_cl = {tare!r}\n")
    return path


@dataclass
class WireSample:
    """One sample's wire integers (serial: counts i32; CAN: raw DBC i16)."""

    volt_cv: int
    envelope_cv: int
    status: int
    ft: tuple[int, ...]


def wire(n: int, kind: str = "serial", seed: int = 0) -> list[WireSample]:
    to_wire = serial_wire if kind == "serial" else can_wire
    it = wire_samples(synthetic_stream(seed), to_wire)
    return [WireSample(*next(it)) for _ in range(n)]


def serial_frame(seq: int, s: WireSample, t_us: int | None = None) -> bytes:
    """One COBS packet + 0x00 (t_us defaults to 2500 µs per seq)."""
    return encode_sample(seq, seq * 2500 if t_us is None else t_us, s.volt_cv, s.ft, s.status, s.envelope_cv)


def can_frames(seq: int, s: WireSample, t_10us: int | None = None) -> list[tuple[int, bytes]]:
    """The three frames (ACT, FT_FORCE, FT_TORQUE) of one sample."""
    return encode_sample_frames(seq, seq * 250 if t_10us is None else t_10us, s.volt_cv, s.envelope_cv,
                                s.status, s.ft[:3], s.ft[3:])


def write_can_log(path: Path, frames: list[tuple[int, bytes]]) -> Path:
    """A python-can log (format by extension) of standard data frames, 1/1200 s apart."""
    with can.Logger(str(path)) as log:
        for i, (fid, data) in enumerate(frames):
            log.on_message_received(can.Message(timestamp=1000.0 + i / 1200.0, arbitration_id=fid, data=data,
                                                dlc=len(data), is_extended_id=False))
    return path


@dataclass
class Run:
    """One ``rtlift`` command run in-process: exit status, stderr lines, summary, estimates."""

    code: int
    err: list[str]
    summary: dict | None
    rows: list[dict] | None

    @property
    def traceback(self) -> bool:
        return any("Traceback" in line for line in self.err)


def rtlift(capsys, *argv: str, summary: Path | None = None, out: Path | None = None) -> Run:
    """Run ``rtlift argv...`` (adding ``--json summary`` and ``--out out`` when given)."""
    args = list(argv)
    if summary is not None:
        args += ["--json", str(summary)]
    if out is not None:
        args += ["--out", str(out)]
    capsys.readouterr()
    code = main(args)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    data = json.loads(summary.read_text()) if summary is not None and summary.exists() else None
    rows = read_estimates(out) if out is not None and out.exists() else None
    return Run(code, err, data, rows)


def read_estimates(path: Path) -> list[dict]:
    """The estimate rows of ``--out`` (metadata lines skipped)."""
    with open(path, encoding="utf-8") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def counters(summary: dict) -> dict[str, int]:
    return {k: summary[k] for k in ("received", "lost", "crc_errors", "duplicates", "resyncs")}

"""A loop's own log as a record file (``rtlift replay LOG --model M --record F.csv``).

:class:`RecordingConverter` stands in for the observer loop's converter during a replay and
keeps, for every sample the loop converts, the sample and what the loop got from it: Cμ and
the envelope as the device applied them (``volt_cv``, ``envelope_cv`` through the
calibration) and ΔCL as measured (forces through the calibration, minus the loop's tare).
:func:`loop_record` turns that into a record (INTERFACES.md), sampled uniformly on the
device's clock:

    k = unwrapped seq − first seq,    t = k / fs

- the samples the loop converted while taring have no ΔCL in the loop; here they get
  CL − tare with the tare the loop then found (the same calibration, the same tare);
- a **gap** — samples lost on the link, or flagged by the device (ADC saturated, sensor
  fault) — is filled so the record stays uniform: Cμ and envelope held at the last sample's
  (as the observer loop holds them), ΔCL interpolated linearly between its neighbours, and
  the row marked ``filled = 1``. A gap longer than :data:`MAX_GAP_SAMPLES`, or filled rows
  beyond :data:`MAX_FILLED_SHARE` of the record, is refused with one line: what the actuator
  did then is not known, and a diagnosis would fit the filler;
- extra columns: ``seq``, ``t_us`` (the device clock as sent; −1 on a lost sample), ``filled``,
  ``flagged``;
  metadata: the source log, its kind, the loop (``observe`` or ``control``), the link
  counters of the replay, the tare, and the number of filled rows and gaps.

``rtlift diagnose`` reads the file like any other record (``--run`` for one long run).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from firmware_io.convert import unwrap_seq
from firmware_io.samples import STATUS_FLAGGED
from rtlift.core.errors import UserError
from rtlift.core.records import Record

MAX_GAP_SAMPLES = 10
"""Longest gap filled (25 ms at 400 Hz, a fifth of a burst period at 8 Hz)."""
MAX_FILLED_SHARE = 0.01
"""Largest share of filled rows in a record."""


@dataclass
class RecordingConverter:
    """The loop's converter, keeping ``(sample, cmu, envelope, dcl | None)`` of each call."""

    converter: Any
    samples: list = field(default_factory=list)
    values: list = field(default_factory=list)

    def __call__(self, sample: Any) -> tuple[float, float, float | None]:
        cmu, env, dcl = self.converter(sample)
        self.samples.append(sample)
        self.values.append((cmu, env, dcl))
        return cmu, env, dcl


def loop_record(rec: RecordingConverter, seq_modulus: int, fs_hz: float, name: str,
                meta: dict[str, Any]) -> Record:
    """The record of what the loop converted (module docstring); :class:`UserError` where it
    cannot be one (no sample, no tare, a gap too long to fill)."""
    conv = rec.converter
    if not rec.samples:
        raise UserError(f"{name}: no samples reached the observer loop; no record to write")
    if conv.tare_cl is None:
        raise UserError(f"{name}: the log ends before the tare ({len(rec.samples)} samples); no ΔCL to write")
    k = unwrap_seq([s.seq for s in rec.samples], seq_modulus)
    n = int(k[-1]) + 1
    cmu = np.empty(n)
    env = np.empty(n)
    dcl = np.full(n, np.nan)
    seq = np.empty(n)
    t_us = np.full(n, np.nan)
    flagged = np.zeros(n)
    have = np.zeros(n, dtype=bool)
    for i, (s, (c, e, d)) in zip(k, zip(rec.samples, rec.values, strict=True), strict=True):
        cmu[i], env[i], seq[i], t_us[i] = c, e, s.seq, s.t_us
        if s.status & STATUS_FLAGGED:
            flagged[i] = 1.0
        elif d is not None:
            dcl[i] = d
        else:                                         # converted while taring: the tare found then
            dcl[i] = conv.cl(s.ft) - conv.tare_cl
        have[i] = True
    missing = ~np.isfinite(dcl)
    runs = _runs(missing)
    if missing[0] or missing[-1]:
        raise UserError(f"{name}: the record would start or end in a gap (flagged samples); nothing to "
                        "interpolate from")
    longest = max((b - a for a, b in runs), default=0)
    if longest > MAX_GAP_SAMPLES or missing.sum() > MAX_FILLED_SHARE * n:
        a, b = max(runs, key=lambda r: r[1] - r[0])
        raise UserError(f"{name}: {int(missing.sum())} of {n} samples lost or flagged, the longest gap "
                        f"{b - a} samples at t = {a / fs_hz:.3f} s; a record fills gaps of at most "
                        f"{MAX_GAP_SAMPLES} samples and {100 * MAX_FILLED_SHARE:g} % of the record")
    last = 0
    for i in range(n):                                # lost samples: inputs held, as the loop holds them
        if have[i]:
            last = i
        else:
            cmu[i], env[i], seq[i] = cmu[last], env[last], (seq[last] + i - last) % seq_modulus
    idx = np.arange(n)
    dcl[missing] = np.interp(idx[missing], idx[~missing], dcl[~missing])
    record_meta = {"fs_hz": f"{fs_hz:g}", **{key: str(v) for key, v in meta.items()},
                   "tare_cl": repr(float(conv.tare_cl)), "samples": str(n), "filled": str(int(missing.sum())),
                   "gaps": str(len(runs)), "lost_in_record": str(int((~have).sum())),
                   "flagged_in_record": str(int(flagged.sum())),
                   "gap_handling": f"gaps of at most {MAX_GAP_SAMPLES} samples filled: inputs held, ΔCL "
                                   "interpolated, rows marked filled = 1"}
    extra = {"seq": seq, "t_us": np.where(np.isfinite(t_us), t_us, -1.0), "filled": missing.astype(float),
             "flagged": flagged}
    return Record(idx / fs_hz, cmu, env, dcl, record_meta, extra, name)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in ``mask``."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))

"""Samples → what the observer needs: ``(cmu, cmu_envelope, dcl)`` with a
:class:`~firmware_io.calibration.Calibration`, and samples → a :class:`rtlift.core.records.Record`.

Per sample (the calibration's equations, evaluated in scalar arithmetic for the 400 Hz loop):

- ``cmu = Cμ(volt_cv / 100)`` (0 while the burst is off, since the drive amplitude is 0),
  ``cmu_envelope = Cμ(envelope_cv / 100)``;
- ``FT = M · ft`` (the link already divided by the counts per unit), ``CL = (s_z Fz cos α −
  s_x Fx sin α) / (½ ρ U∞² c b)``, ``dcl = CL − CL_tare``;
- ``dcl`` is ``None`` when the sample is flagged (ADC saturated or sensor fault), and while
  the tare is still being measured.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_io.calibration import Calibration, CalibrationError
from firmware_io.samples import STATUS_FLAGGED, Sample
from rtlift.core.rate import FS_HZ
from rtlift.core.records import Record

RECORD_EXTRA = ("seq", "t_device", "volts", "envelope_volts", "status",
                "fx", "fy", "fz", "tx", "ty", "tz", "host_time")


class Converter:
    """Streaming conversion of samples; call it with each sample in arrival order.

    Tare: ``calibration.tare_cl`` if stored; otherwise the mean CL of the samples with the
    actuator off (drive amplitude 0, not flagged) among the first ``tare_seconds · fs_hz``
    samples received; ``dcl`` is ``None`` until then. :class:`CalibrationError` if that
    window holds no such sample.
    """

    def __init__(self, calibration: Calibration | None = None, fs_hz: float = FS_HZ) -> None:
        cal = calibration or Calibration()
        self.calibration = cal
        a = math.radians(cal.alpha_deg)
        self._kz = cal.sign_fz * math.cos(a) / cal.q_area
        self._kx = cal.sign_fx * math.sin(a) / cal.q_area
        m = cal.matrix
        self._row_x = tuple(m[0]) if m is not None else None
        self._row_z = tuple(m[2]) if m is not None else None
        self._kappa = cal.kappa
        self._table_v = tuple(cal.cmu_table_v)
        self._table = tuple(cal.cmu_table)
        self.tare_cl: float | None = cal.tare_cl
        self._tare_window = max(1, int(round(cal.tare_seconds * fs_hz)))
        self._tare_seen = 0
        self._tare_sum = 0.0
        self._tare_n = 0

    def cmu(self, volts: float) -> float:
        """Cμ = κ V², or the hot-wire table (linear, clamped at its ends) — as the calibration."""
        v = abs(volts)
        tv = self._table_v
        if not tv:
            return self._kappa * v * v
        if v <= tv[0]:
            return self._table[0]
        if v >= tv[-1]:
            return self._table[-1]
        i = bisect_right(tv, v)
        v0, v1 = tv[i - 1], tv[i]
        c0, c1 = self._table[i - 1], self._table[i]
        return c0 + (c1 - c0) * (v - v0) / (v1 - v0)

    def cl(self, ft: Sequence[float]) -> float:
        """Untared CL from the six link values (calibration matrix applied)."""
        if self._row_x is None:
            fx, fz = ft[0], ft[2]
        else:
            a, b = self._row_x, self._row_z
            fx = a[0] * ft[0] + a[1] * ft[1] + a[2] * ft[2] + a[3] * ft[3] + a[4] * ft[4] + a[5] * ft[5]
            fz = b[0] * ft[0] + b[1] * ft[1] + b[2] * ft[2] + b[3] * ft[3] + b[4] * ft[4] + b[5] * ft[5]
        return self._kz * fz - self._kx * fx

    def __call__(self, sample: Sample) -> tuple[float, float, float | None]:
        cmu = self.cmu(sample.volt_cv * 0.01)
        env = self.cmu(sample.envelope_cv * 0.01)
        flagged = sample.status & STATUS_FLAGGED
        if self.tare_cl is None:
            self._tare_step(sample, flagged)
            return cmu, env, None
        if flagged:
            return cmu, env, None
        return cmu, env, self.cl(sample.ft) - self.tare_cl

    def _tare_step(self, sample: Sample, flagged: int) -> None:
        self._tare_seen += 1
        if sample.volt_cv == 0 and not flagged:
            self._tare_sum += self.cl(sample.ft)
            self._tare_n += 1
        if self._tare_seen >= self._tare_window:
            if self._tare_n == 0:
                raise CalibrationError(
                    "cannot tare: the actuator is never off in the first "
                    f"{self.calibration.tare_seconds} s (store tare_cl in the calibration)")
            self.tare_cl = self._tare_sum / self._tare_n


def unwrap_seq(seqs: Sequence[int], modulus: int) -> np.ndarray:
    """Sample indices from a wrapping ``seq`` (first sample 0; gaps kept)."""
    s = np.asarray(seqs, dtype=np.int64)
    if s.size == 0:
        return s
    steps = np.mod(np.diff(s), modulus)
    return np.concatenate([[0], np.cumsum(steps)])


def record_from_samples(samples: Sequence[Sample], calibration: Calibration | None = None, *,
                        fs_hz: float = FS_HZ, seq_modulus: int = 1 << 16, name: str = "record",
                        meta: dict[str, Any] | None = None) -> Record:
    """A record (INTERFACES.md) from samples as captured through a link.

    ``t`` = (unwrapped ``seq`` − first) / ``fs_hz`` (the device clock; a lost sample leaves a
    gap), ``cmu``/``cmu_envelope`` from the drive and envelope voltages, ``dcl`` tared as
    :meth:`Calibration.tare_from` does over the unflagged samples (or the stored tare).
    Flagged samples (ADC saturated, sensor fault) have no valid ΔCL and are left out.
    Extra columns: :data:`RECORD_EXTRA`.
    """
    cal = calibration or Calibration()
    n = len(samples)
    if n == 0:
        raise CalibrationError("no samples to make a record from")
    idx = unwrap_seq([s.seq for s in samples], seq_modulus)
    volts = np.array([s.volt_cv for s in samples], dtype=float) * 0.01
    env_volts = np.array([s.envelope_cv for s in samples], dtype=float) * 0.01
    status = np.array([s.status for s in samples], dtype=np.int64)
    ft = np.array([s.ft for s in samples], dtype=float).reshape(n, 6)
    ft_si = ft @ np.asarray(cal.matrix, dtype=float).T if cal.matrix is not None else ft
    cl = np.asarray(cal.cl_from_ft(ft_si), dtype=float)
    flagged = (status & STATUS_FLAGGED) != 0
    tare = cal.tare_cl
    if tare is None:
        tare = cal.tare_from(cl, np.where(flagged, np.nan, volts), fs_hz)
    keep = ~flagged
    t_device = np.array([s.t_us for s in samples], dtype=float) * 1e-6
    extra = {
        "seq": np.array([s.seq for s in samples], dtype=float), "t_device": t_device,
        "volts": volts, "envelope_volts": env_volts, "status": status.astype(float),
        **{k: ft[:, i] for i, k in enumerate(("fx", "fy", "fz", "tx", "ty", "tz"))},
        "host_time": np.array([s.host_time for s in samples], dtype=float),
    }
    record_meta = {"fs_hz": f"{fs_hz:g}", "samples": str(int(keep.sum())), "flagged": str(int(flagged.sum())),
                   "tare_cl": repr(float(tare))}
    record_meta.update({k: str(v) for k, v in (meta or {}).items()})
    return Record(idx[keep] / fs_hz, np.asarray(cal.cmu_from_volts(volts[keep]), dtype=float),
                  np.asarray(cal.cmu_from_volts(env_volts[keep]), dtype=float), cl[keep] - tare,
                  record_meta, {k: v[keep] for k, v in extra.items()}, name)


def capture(link: Any, n: int, silence_s: float = 1.0) -> list[Sample]:
    """Up to ``n`` samples from a link; stops early when the device is gone or silent for
    ``silence_s`` seconds."""
    out: list[Sample] = []
    while len(out) < n:
        sample = link.recv(silence_s)
        if sample is None:
            break
        out.append(sample)
    return out

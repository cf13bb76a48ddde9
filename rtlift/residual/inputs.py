"""What kind of experiment a record is, from its commanded signal alone (never its name).

A record's input is described by what an experimenter sets (:func:`input_descriptor`):

- ``burst_period_s``: median spacing of burst onsets (0 with fewer than two bursts);
- ``on_time_s``: median length of a burst (samples with Cμ > 0 in a row);
- ``envelope_hz``: fundamental of a periodic envelope, the power-weighted mean frequency of the
  Hann periodogram's main lobe (±2 bins) around its strongest bin; 0 if not periodic (that lobe
  holds less than half the envelope's AC power);
- ``bandwidth_hz``: the frequency below which 90 % of the envelope's AC power lies;
- ``level_lo``, ``level_hi``: the envelope's 2nd and 98th percentiles (Cμ);
- ``level_mean``: its mean; ``duration_s``: the record's length.

Two inputs are of one kind when every feature agrees within its tolerance
(:data:`TOLERANCES`): d = maxᵢ |aᵢ − bᵢ| / tolᵢ(a, b) ≤ 1 (:func:`descriptor_distance`). The
tolerances are what tells one standard experiment from another, not noise: a burst period is
set to the sample (a relative 3 %), an on-time to a sample, a periodic envelope's frequency to
5 % (k = 0.125 and k = 0.25 are a factor 2 apart), a bandwidth to 30 % (the 90 % point of one
record's envelope spectrum moves with the seed: over ten clean bench ``random`` inputs it spread
from 1.20 to 1.52 Hz, a largest pairwise distance of 0.70), levels to 10 % of the larger top
level. The record's duration is reported, not matched: a shorter run of one experiment is the
same kind.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.core.rate import FS_HZ
from rtlift.core.records import Record

BANDWIDTH_POWER = 0.9          # share of the envelope's AC power below its bandwidth


def _onsets(cmu: np.ndarray) -> np.ndarray:
    return np.flatnonzero((cmu[1:] > 0) & (cmu[:-1] <= 0)) + 1


def input_descriptor(rec: Record) -> dict[str, float]:
    """The record's input features (module docstring), in SI units."""
    fs = rec.fs_hz
    cmu, env = np.asarray(rec.cmu, dtype=float), np.asarray(rec.cmu_envelope, dtype=float)
    on = _onsets(cmu)
    if cmu.size and cmu[0] > 0:
        on = np.concatenate([[0], on])
    period = float(np.median(np.diff(on)) / fs) if on.size >= 2 else 0.0
    ends = np.flatnonzero((cmu[:-1] > 0) & (cmu[1:] <= 0)) + 1
    lengths = [int(e - o) for o in on for e in ends[ends > o][:1]]
    on_time = float(np.median(lengths) / fs) if lengths else 0.0
    ac = env - env.mean()
    spec = np.abs(np.fft.rfft(ac * np.hanning(ac.size))) ** 2 if ac.size > 8 else np.zeros(2)
    f = np.fft.rfftfreq(max(ac.size, 2), 1.0 / fs)[:spec.size]
    total = float(spec[1:].sum())
    if total > 0:
        k = int(np.argmax(spec[1:])) + 1
        lobe = slice(max(1, k - 2), k + 3)                 # the Hann window's main lobe, ±2 bins
        share = float(spec[lobe].sum()) / total
        periodic = float(np.sum(f[lobe] * spec[lobe]) / spec[lobe].sum()) if share > 0.5 else 0.0
        cum = np.cumsum(spec[1:]) / total
        bandwidth = float(f[1:][int(np.searchsorted(cum, BANDWIDTH_POWER))])
    else:
        periodic, bandwidth = 0.0, 0.0
    lo, hi = (float(x) for x in np.percentile(env, [2.0, 98.0])) if env.size else (0.0, 0.0)
    return {"burst_period_s": period, "on_time_s": on_time, "envelope_hz": periodic,
            "bandwidth_hz": bandwidth, "level_lo": lo, "level_hi": hi,
            "level_mean": float(env.mean()) if env.size else 0.0, "duration_s": cmu.size / fs}


def _rel(rel: float, floor: float = 0.0):
    return lambda a, b: max(rel * max(abs(a), abs(b)), floor)


TOLERANCES: dict[str, Any] = {
    "burst_period_s": _rel(0.03, 1e-9),
    "on_time_s": lambda a, b: max(0.03 * max(a, b), 1.01 / FS_HZ),   # one sample
    "envelope_hz": _rel(0.05, 1e-3),
    "bandwidth_hz": _rel(0.3, 0.02),
}
"""Per feature: (a, b) ↦ the difference that still counts as the same setting."""
LEVEL_TOLERANCE = 0.1          # of the larger top level


def descriptor_distance(a: dict[str, float], b: dict[str, float]) -> tuple[float, str]:
    """d = maxᵢ |aᵢ − bᵢ| / tolᵢ over the features (module docstring) and the feature that sets
    it; d ≤ 1: the same kind of input."""
    scale = max(a["level_hi"], b["level_hi"], 1e-300)
    parts = {k: abs(a[k] - b[k]) / tol(a[k], b[k]) for k, tol in TOLERANCES.items()}
    for k in ("level_lo", "level_hi", "level_mean"):
        parts[k] = abs(a[k] - b[k]) / (LEVEL_TOLERANCE * scale)
    worst = max(parts, key=parts.get)
    return float(parts[worst]), worst


def describe(d: dict[str, float]) -> str:
    """One line: the input's kind in an experimenter's words."""
    bursts = (f"bursts every {1e3 * d['burst_period_s']:.1f} ms, {1e3 * d['on_time_s']:.1f} ms on"
              if d["burst_period_s"] > 0 else "no burst train")
    env = (f"periodic envelope at {d['envelope_hz']:.3g} Hz" if d["envelope_hz"] > 0 else
           f"envelope band {d['bandwidth_hz']:.3g} Hz")
    return (f"{bursts}; {env}; Cmu {d['level_lo']:.4g} to {d['level_hi']:.4g}; "
            f"{d['duration_s']:.1f} s")


def best_match(descriptors: dict[str, dict[str, float]], d: dict[str, float]) -> tuple[str | None, float, str]:
    """The key of ``descriptors`` nearest to ``d`` (None if empty), its distance and the feature
    that sets the distance."""
    best: tuple[str | None, float, str] = (None, math.inf, "")
    for key, other in descriptors.items():
        dist, worst = descriptor_distance(d, other)
        if dist < best[1]:
            best = (key, dist, worst)
    return best


def nearest_dynamics(descriptors: dict[str, dict[str, float]], d: dict[str, float]) -> str | None:
    """The key of ``descriptors`` whose input excites the model most alike: the same burst
    setting (burst period and on-time within :data:`TOLERANCES`, else any), then the nearest
    envelope bandwidth on a log scale, |ln(B_a / B_b)|. The model's misfit is dynamic: a 1 Hz
    random envelope is nearer a 0.5 Hz sine than a 0.02 Hz static sweep, however the sweep's
    slow period compares in :func:`descriptor_distance`."""
    def key(k: str) -> tuple[bool, float]:
        o = descriptors[k]
        same = all(abs(o[f] - d[f]) <= TOLERANCES[f](o[f], d[f]) for f in ("burst_period_s", "on_time_s"))
        return (not same, abs(math.log(max(o["bandwidth_hz"], 1e-6) / max(d["bandwidth_hz"], 1e-6))))
    return min(descriptors, key=key) if descriptors else None

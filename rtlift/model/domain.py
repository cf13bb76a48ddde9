"""The domain of a model: the burst patterns and the Cμ range it was identified on (issue 18).

``rtlift identify`` stores it in the model file (``provenance.domain``)::

    {"burst_periods_s": [...],   # intervals between burst onsets seen (distinct, ±1 sample)
     "isolated_after_s": L/fs,   # an interval of one burst response (kernel length L) or more
     "isolated_bursts": bool,    #   is an isolated burst; were isolated bursts seen?
     "cmu_max": ..., "cmu_envelope_max": ...}

A record or a live stream *leaves* the domain when a burst interval is neither within
``PERIOD_TOLERANCE`` of one seen nor isolated (when isolated bursts were seen), or when its
burst Cμ or envelope exceeds the maximum seen by more than ``CMU_TOLERANCE``. Leaving it is a
warning (one line), never an error: the model still runs, it is only not validated there.
Onsets are the samples where Cμ turns positive (a burst is on where ``cmu`` > 0).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from rtlift.core.records import burst_onsets

PERIOD_TOLERANCE = 0.1          # relative
CMU_TOLERANCE = 0.05            # relative


def burst_intervals(cmu: np.ndarray) -> np.ndarray:
    """Samples between consecutive burst onsets (Cμ turning positive)."""
    return np.diff(burst_onsets(cmu, threshold=0.0))


def domain_of(records: Iterable[Any], fs_hz: float, isolated_samples: int) -> dict[str, Any]:
    """The domain of identification ``records`` (objects with ``cmu`` and ``cmu_envelope``)."""
    records = list(records)
    gaps = np.concatenate([burst_intervals(r.cmu) for r in records] + [np.empty(0, int)])
    close = np.sort(gaps[gaps < isolated_samples])
    periods: list[int] = []
    for g in close:
        if not periods or g > periods[-1] + 1:
            periods.append(int(g))
    return {"burst_periods_s": [p / fs_hz for p in periods],
            "isolated_after_s": isolated_samples / fs_hz,
            "isolated_bursts": bool(np.any(gaps >= isolated_samples)),
            "cmu_max": float(max(np.max(r.cmu) for r in records)),
            "cmu_envelope_max": float(max(np.max(r.cmu_envelope) for r in records))}


def envelope_reach(envelope: np.ndarray, fs_hz: float, share: float = 0.95) -> dict[str, float]:
    """How far in frequency a training record's envelope reaches: ``f95_hz``, the frequency below
    which ``share`` of its variance lies (periodogram of the envelope less its mean, cumulated), and
    ``share_above_1hz``, the part of its variance above 1 Hz. The model's dynamics are fitted on that
    envelope, so above ``f95_hz`` they are extrapolated (docs/results/control.md, "Tenth pass": the
    paper's ``sine_k0125`` of plant draw 1 reaches 0.49 Hz, the bench's ``random`` 1.67 Hz)."""
    x = np.asarray(envelope, float)
    p = np.abs(np.fft.rfft(x - x.mean())) ** 2
    f = np.fft.rfftfreq(x.size, 1.0 / fs_hz)
    total = float(p[1:].sum())
    if x.size < 2 or total <= 0.0:
        return {"f95_hz": 0.0, "share_above_1hz": 0.0}
    cum = np.cumsum(p[1:]) / total
    return {"f95_hz": float(f[1:][min(int(np.searchsorted(cum, share)), cum.size - 1)]),
            "share_above_1hz": float(p[1:][f[1:] > 1.0].sum() / total)}


def _period_outside(domain: dict[str, Any], gap_s: float) -> bool:
    if gap_s >= domain["isolated_after_s"]:
        return not domain["isolated_bursts"]
    return not any(abs(gap_s - p) <= PERIOD_TOLERANCE * p for p in domain["burst_periods_s"])


def _seen(domain: dict[str, Any]) -> str:
    periods = ", ".join(f"{p:.3g}" for p in domain["burst_periods_s"]) or "none"
    iso = " and isolated bursts" if domain["isolated_bursts"] else ""
    return f"burst periods {periods} s{iso}, Cμ up to {domain['cmu_max']:.4g}"


def outside_domain(domain: dict[str, Any] | None, cmu: np.ndarray, cmu_envelope: np.ndarray,
                   fs_hz: float) -> str | None:
    """One line saying how a record leaves ``domain``, or None (also when there is no domain)."""
    if not domain:
        return None
    why = []
    gaps = np.unique(burst_intervals(cmu)) / fs_hz
    out = [g for g in gaps if _period_outside(domain, g)]
    if out:
        why.append(f"burst periods {', '.join(f'{g:.3g}' for g in out[:4])}{' …' if len(out) > 4 else ''} s")
    top = max(float(np.max(cmu, initial=0.0)), float(np.max(cmu_envelope, initial=0.0)))
    limit = max(domain["cmu_max"], domain["cmu_envelope_max"])
    if top > limit * (1 + CMU_TOLERANCE):
        why.append(f"Cμ {top:.4g}")
    if not why:
        return None
    return f"outside the model's domain: {' and '.join(why)} (identified on {_seen(domain)})"


class DomainWatch:
    """:func:`outside_domain` for a live stream, one sample at a time (no allocation): ``step``
    returns the line the first time the stream leaves the domain, else None."""

    def __init__(self, domain: dict[str, Any], fs_hz: float) -> None:
        self.domain = domain
        self.fs_hz = float(fs_hz)
        self._limit = max(domain["cmu_max"], domain["cmu_envelope_max"]) * (1 + CMU_TOLERANCE)
        self._on = False
        self._k = 0
        self._last_onset = -1
        self.reported = False

    def step(self, cmu: float, cmu_envelope: float) -> str | None:
        k = self._k
        self._k = k + 1
        on = cmu > 0
        why = None
        if on and not self._on:
            if self._last_onset >= 0 and _period_outside(self.domain, (k - self._last_onset) / self.fs_hz):
                why = f"burst period {(k - self._last_onset) / self.fs_hz:.3g} s"
            self._last_onset = k
        self._on = on
        if why is None and max(cmu, cmu_envelope) > self._limit:
            why = f"Cμ {max(cmu, cmu_envelope):.4g}"
        if why is None or self.reported:
            return None
        self.reported = True
        return f"outside the model's domain at sample {k}: {why} (identified on {_seen(self.domain)})"


class WatchedConverter:
    """A sample converter (``firmware_io.Converter``) that also feeds a :class:`DomainWatch` and
    hands its one line to ``on_leave``; every other attribute is the converter's."""

    def __init__(self, converter: Any, watch: DomainWatch, on_leave: Callable[[str], None]) -> None:
        self._converter = converter
        self._watch = watch
        self._on_leave = on_leave

    def __call__(self, sample: Any) -> tuple[float, float, float | None]:
        cmu, env, dcl = self._converter(sample)
        if not self._watch.reported:
            line = self._watch.step(cmu, env)
            if line is not None:
                self._on_leave(line)
        return cmu, env, dcl

    def __getattr__(self, name: str) -> Any:
        return getattr(self._converter, name)


def watch_domain(converter: Any, model: Any, command: str) -> Any:
    """``converter`` (for an observer loop, given to it when it is made) that also says on stderr,
    once, when the live stream leaves ``model``'s domain; a model file without one: ``converter``
    itself (nothing is watched)."""
    domain = model.provenance.get("domain")
    if not domain:
        return converter
    return WatchedConverter(converter, DomainWatch(domain, model.fs_hz),
                            lambda line: print(f"{command}: warning: {line}", file=sys.stderr, flush=True))

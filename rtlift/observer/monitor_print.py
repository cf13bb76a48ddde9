"""What the live departure monitor needs to judge a model's residual, from the model's own records.

Computed when the model is identified (``rtlift identify``, :func:`rtlift.api.identify`) and stored in
its fingerprint (``fingerprint["monitor"]``), so a user's model on a user's plant is judged by
thresholds from the user's data, not from the plants the team calibrated on:

- ``operating_point``: the model's own slow misfit against its lift, g(m). Over 1-s blocks of the
  identification records with a loop's kind of input and the static sweep, e_b = c_r + g(m_b):
  e_b the block's mean residual ΔCL − ΔCL_m, m_b its mean model lift, c_r each record's own
  offset (its tare), g piecewise linear on :data:`KNOTS` knots at quantiles of m_b, g = 0 at the
  median (least squares). The monitor removes g(m_b) before its bias, gain and trend tests: a step
  of the operating point then moves none of them by the misfit the model had there all along.
- ``thresholds``: the null distribution of every monitor statistic on the model's own residual.
  The observer and the monitor (g removed, thresholds off, every evaluation kept) run over each
  of those records exactly as the live loop steps them, and over a moving-block bootstrap of
  them: ``BOOT_HOURS`` of streams made of :data:`SEGMENT_S`-second segments cut at random from
  the records (after their start-up), each joint marked to the monitor as a step of the
  operating point (a loop tracking steps), so every window the tests judge holds the record's
  own residual at two operating points, as a loop's do. Threshold = the largest value each
  statistic held for ``persist`` consecutive evaluations over records and bootstrap, times
  :data:`OWN_MARGIN`; a statistic judged too rarely there (:data:`MIN_JUDGED`), or never above 0
  (``whiteness``, a lag-1 correlation, can stay negative), keeps the global constant.
- ``lift_range``: the largest |ΔCL_m| on those records (the start-up's step size, :class:`Settle`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.core.records import Record

PRINT_VERSION = 1
KNOTS = 6
"""Knots of g(m): quantiles 0, 0.2, …, 1 of the blocks' model lift."""
SEGMENT_S = 12.0
"""Bootstrap segment: a loop's step period (steps every 10–12 s)."""
BOOT_HOURS = 1.0
"""Hours of bootstrap stream per model (about 5 s of identification time on this machine)."""
BOOT_SEED = 46
OWN_MARGIN = 1.75
"""Threshold = the model's own persistent maximum × this. Set on the calibration draws 1–3 of the plant
family (``benchmarks.monitor_family --draws 1-3``, each draw's model identified on its own campaign,
one clean closed loop of 120 s with steps every 10 s each): the clean loops' persistent maxima reached
at most 1.38 × the model's own (draw 2, ``gain``; the others ≤ 0.98); 1.25 (the global constants'
headroom) × 1.38, rounded up to a quarter. docs/results/monitor.md."""
MIN_JUDGED = 600
"""A statistic evaluated (non-zero) fewer times than this on the model's own records — 10 minutes of
evaluations; ``hold`` needs the operating point held, ``gain`` it moving — keeps the global
constant (``null`` in the print, said in the monitor's summary)."""


def _loop_like(name: str) -> bool:
    from rtlift.observer.monitor import LOOP_LIKE, QUASI_STATIC

    return name.startswith(LOOP_LIKE) or name == QUASI_STATIC


def observer_traces(model: Any, rec: Record) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(z, ΔCL_m, ν) of ``rec`` through the model's observer, stepped as the live loop steps it."""
    from rtlift.observer import Observer

    obs = Observer.from_model(model)
    n = len(rec)
    m, nu = np.empty(n), np.empty(n)
    step = obs.step
    for k, (c, v, z) in enumerate(zip(rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist(), strict=True)):
        est = step(c, v, None if z != z else z)
        m[k], nu[k] = est.model_dcl, est.innovation
    return np.asarray(rec.dcl, dtype=float), m, nu


def operating_point_misfit(parts: list[tuple[np.ndarray, np.ndarray]], block: int,
                           knots: int = KNOTS) -> dict[str, list[float]] | None:
    """g(m) from (e, m) per record (module docstring): ``{"m": knots, "e": g at the knots}``;
    None with fewer than 3 blocks per free parameter."""
    eb, mb, rid = [], [], []
    for r, (e, m) in enumerate(parts):
        nb = e.size // block
        if nb < 2:
            continue
        ee = e[: nb * block].reshape(nb, block)
        mm = m[: nb * block].reshape(nb, block)
        ok = np.isfinite(ee).all(axis=1) & np.isfinite(mm).all(axis=1)
        eb.append(ee[ok].mean(axis=1))
        mb.append(mm[ok].mean(axis=1))
        rid.append(np.full(int(ok.sum()), r))
    if not eb:
        return None
    e, m, r = np.concatenate(eb), np.concatenate(mb), np.concatenate(rid)
    grid = np.unique(np.quantile(m, np.linspace(0.0, 1.0, knots)))
    records = np.unique(r)
    if grid.size < 2 or e.size < 3 * (grid.size - 1 + records.size):
        return None
    hats = np.column_stack([np.interp(m, grid, np.eye(grid.size)[j]) for j in range(grid.size)])
    dummies = (r[:, None] == records[None, :]).astype(float)
    X = np.column_stack([hats[:, 1:], dummies])          # g(grid[0]) = 0: the offsets carry the level
    coef = np.linalg.lstsq(X, e, rcond=None)[0]
    g = np.concatenate([[0.0], coef[: grid.size - 1]])
    g -= np.interp(np.median(m), grid, g)
    return {"m": grid.tolist(), "e": g.tolist()}


def monitor_print(model: Any, records: list[Record], start: int, *, hours: float = BOOT_HOURS,
                  seed: int = BOOT_SEED) -> dict[str, Any] | None:
    """The model's own monitor print (module docstring); None when no record has a loop's kind of
    input or the model has no fingerprint scale."""
    from rtlift.observer.monitor import TESTS, DepartureMonitor, Settle, input_gain_of, monitor_arrays, persistent_max
    from rtlift.residual.fingerprint import record_type

    probe = DepartureMonitor.for_model(model)
    block = probe.block
    traces = []
    for rec in records:
        if _loop_like(record_type(rec)) and len(rec) - start >= 4 * block:
            z, m, nu = observer_traces(model, rec)
            traces.append((record_type(rec), z, m, nu, np.asarray(rec.cmu_envelope, dtype=float)))
    if not traces:
        return None
    lift_range = float(max(np.nanmax(np.abs(m)) for _, _, m, _, _ in traces))
    op = operating_point_misfit([(z[start:] - m[start:], m[start:]) for _, z, m, _, _ in traces], block)
    own = {"lift_range": lift_range, "operating_point": op}

    def monitor() -> DepartureMonitor:
        mon = DepartureMonitor(probe.scale, model.fs_hz, probe.config, probe.hold_scale,
                               Settle.of_model(model, probe.scale, lift_range), op, input_gain_of(model, lift_range))
        mon.thresholds = dict.fromkeys(TESTS, math.inf)
        mon.history = []
        return mon

    worst = dict.fromkeys(TESTS, 0.0)
    by = dict.fromkeys(TESTS, "")
    judged = dict.fromkeys(TESTS, 0)
    seen = 0.0

    def take(mon: DepartureMonitor, name: str) -> None:
        for t in TESTS:
            judged[t] += sum(1 for h in mon.history if h[t] != 0)
            v = persistent_max([h[t] for h in mon.history], mon.config.persist)
            if v > worst[t]:
                worst[t], by[t] = v, name
    for name, z, m, nu, u in traces:
        mon = monitor()
        monitor_arrays(mon, z, m, nu, u)
        take(mon, name)
        seen += len(z) / model.fs_hz
    # the moving-block bootstrap: segments after each record's start-up, joints marked as steps
    seg = int(SEGMENT_S * model.fs_hz)
    first = start + probe.settle.samples(probe.settle.start_size(probe.scale), probe.scale, model.fs_hz)
    pool = [(z[first:], m[first:], nu[first:], u[first:]) for _, z, m, nu, u in traces if len(z) - first >= seg]
    rng = np.random.default_rng(seed)
    stream_segments = int(round(600.0 / SEGMENT_S))        # streams of 10 minutes, each its own run
    streams = int(math.ceil(hours * 3600.0 / (stream_segments * SEGMENT_S))) if pool else 0
    for s in range(streams):
        picks = [pool[int(rng.integers(len(pool)))] for _ in range(stream_segments)]
        cuts = [int(rng.integers(0, len(p[0]) - seg + 1)) for p in picks]
        z, m, nu, u = (np.concatenate([p[i][c:c + seg] for p, c in zip(picks, cuts, strict=True)]) for i in range(4))
        mon = monitor()
        levels = np.array([p[1][c:c + seg].mean() for p, c in zip(picks, cuts, strict=True)])
        mon.set_steps(np.arange(1, stream_segments) * seg, np.diff(levels))   # each joint a step of the lift
        monitor_arrays(mon, z, m, nu, u)
        take(mon, f"bootstrap {s}")
        seen += len(z) / model.fs_hz
    thresholds = {t: round(OWN_MARGIN * v, 6) if judged[t] >= MIN_JUDGED and v > 0 else None
                  for t, v in worst.items()}
    return {"version": PRINT_VERSION, **own, "thresholds": thresholds, "persistent_max": worst,
            "set_by": by, "judged": judged, "hours": seen / 3600.0, "margin": OWN_MARGIN,
            "source": f"persistent maxima over {len(traces)} identification records and {streams} bootstrap "
                      f"streams, {seen / 3600.0:.2f} h, × {OWN_MARGIN}"}


"""What the diagnosis leaves unexplained: the report's ``unexplained`` lines — features of the final
training residual that still depart from the fingerprint, candidates the evidence points at but the
held-out records did not support, and a slow trend the record is too short to separate
(:func:`slow_trend_line`) — with the spectrum bands an accepted entry accounts for
(:func:`explained_bands`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtlift.diagnose.diagnosis import Trial
from rtlift.effects import BY_NAME
from rtlift.effects.zero_drift import ZeroDriftEffect
from rtlift.residual.fingerprint import Z_DEPART, coef_departure, level_departure, psd_departure
from rtlift.residual.stats import TestResult


def unexplained(tests: dict[str, TestResult], fp: dict[str, Any] | None, trials: list[Trial],
                seconds: float = 0.0, drift_holds: bool = False) -> list[str]:
    """One plain line per feature of the final training residual that still departs from the
    fingerprint, per candidate whose evidence departs but whose fit the validation records
    did not support, and for a slow trend the record is too short to separate
    (:func:`slow_trend_line`). A residual line inside the band of an accepted resonance or
    pickup (:func:`explained_bands`) is that entry's leftover, not listed."""
    if fp is None:
        return [f"{k}: {tests[k].detail}" for k in ("slow_trend", "gain_trend", "direction", "level")
                if tests[k].significant]
    deps = [coef_departure(tests[key], fp, what) for key, what in
            (("slow_trend", "offset drift"), ("gain_trend", "gain drift"),
             ("direction", "falling-Cmu gain difference"))]
    deps.append(level_departure(tests["level"], fp))
    lines = [f"{d.text}: no accepted entry explains it" for d in deps if d.departs]
    slow = slow_trend_line(tests["slow_trend"], fp, seconds, trials, drift_holds)
    lines += [slow] if slow else []
    spec = tests["spectrum"].data
    f = np.asarray(spec["f"])
    df = float(f[1])
    excess = np.log(np.maximum(spec["psd"], 1e-300)) - np.interp(f, fp["psd"]["f_hz"], fp["psd"]["log10"]) * np.log(10)
    bands = explained_bands(trials, df)
    for k in np.argsort(excess)[::-1][:3]:
        if any(lo <= f[k] <= hi for lo, hi in bands):
            continue
        dep = psd_departure(tests["spectrum"], fp, [(f[k] - 0.5 * df, f[k] + 0.5 * df)], f"{f[k]:.1f} Hz")
        if dep.departs:
            lines.append(f"residual power at {dep.text}: stands above the model's own residual")
    lines += [f"{t.name} is pointed at by the evidence but not accepted: {t.evidence}"
              for t in trials if not t.accepted and t.params and t.kind == "effect"]
    return lines


def explained_bands(trials: list[Trial], df: float) -> list[tuple[float, float]]:
    """Frequency bands (Hz) an accepted entry accounts for: a ``sensor_resonance``'s half-power
    band f(1 ± ζ), a ``periodic_disturbance``'s lines (the fundamental and its harmonics as
    sampled) ± 1.5 bins (the window its fit searches); each widened by half a spectrum bin
    ``df``, the width of the bin a line is reported at. Each effect's own
    (:attr:`rtlift.effects.base.Effect.bands`)."""
    bands = []
    for t in trials:
        of = getattr(BY_NAME.get(t.name), "bands", None) if t.accepted else None    # the effect's own
        if of is not None:
            bands += of(t.params, df)
    return bands


Z_NOTE = 2.0
"""|z| of the offset drift against the print from which an unseparated slow trend is reported
(a line in ``unexplained``, never an accepted entry): the two-sided 95 % point of the z-test's own
null (N(0, 1)), checked on clean runs (``benchmarks.null_rate``)."""


def slow_trend_line(test: TestResult, fp: dict[str, Any] | None, seconds: float, trials: list[Trial],
                    drift_holds: bool = False) -> str:
    """The line for a slow trend the training record cannot tell from the model's own slow
    misfit: the residual's offset drift b (ΔCL/s, :func:`.residual.slow_trend`) does not depart
    from the print's (|z| < ``Z_DEPART``) but either stands ``Z_NOTE`` ≤ |z| from it or a
    ``zero_drift`` fitted alone lowers the held-out error at the confirmation bar
    (``drift_holds``: the held-out records see it too), and no accepted ``zero_drift`` takes it.

    How long a record would tell: both standard errors of a trend fitted over T seconds of a
    stationary misfit fall as T^(−3/2) (OLS slope over 1 s blocks); a drift that approaches its
    end value (the slow kind: thermal) adds a fixed change Δ = b T however long the record, its
    slope falls as 1/T, so z grows as √T and reaches ``Z_DEPART`` at
    N = T (Z_DEPART / |z|)² (a drift that kept its rate would tell sooner: T (Z_DEPART/|z|)^(2/3))."""
    if fp is None or seconds <= 0 or any(t.accepted and t.name == ZeroDriftEffect.name for t in trials):
        return ""
    dep = coef_departure(test, fp, "offset drift", "/s")
    z = dep.z
    if dep.departs or (abs(z) < Z_NOTE and not drift_holds) or z == 0.0:
        return ""
    change = float(test.data["coef"]) * seconds
    need = seconds * (Z_DEPART / abs(z)) ** 2
    return (f"slow trend {change:+.3f} dCL over the record ({seconds:.0f} s; {dep.text}), not separable from the "
            f"model's own misfit on a record this short; a record of >= {math.ceil(need):.0f} s would tell")

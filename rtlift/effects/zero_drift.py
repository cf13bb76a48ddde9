"""The ``zero_drift`` effect: thermal drift of the sensor zero (ΔCL units).

Fit: offset + rate·t, or offset + A(1 − e^{−t/τ}) (τ on a grid), linear LS. Evidence: the
residual's offset drift against the print's. Stage :class:`rtlift.blocks.zero_drift.ZeroDrift`;
the observer's random-walk bias state covers it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from rtlift.blocks.zero_drift import ZeroDrift
from rtlift.core.records import Record
from rtlift.effects.base import Effect, no_print
from rtlift.effects.surgery import Context, Fitted, augment, predict
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, coef_departure
from rtlift.residual.stats import TestResult


class ZeroDriftEffect(Effect):
    """d(k) = offset + rate · t_k, or offset + amplitude (1 − exp(−t_k/τ))."""

    name = ZeroDrift.name
    row = 40
    meaning = "thermal drift of the sensor zero (ΔCL units)"
    params = {"rate_per_s": (4.0e-4, 2.0e-4, 1.5e-3, "ΔCL/s")}
    alternatives = {"amplitude": (0.02, 0.01, 0.05, "ΔCL"), "time_constant_s": (20.0, 5.0, 60.0, "s")}
    path = "additive"
    stages = (ZeroDrift,)
    observed = True

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        e = train.dcl - predict(base, train).total
        t = np.arange(e.size) / ctx.fs
        s = ctx.start
        X = np.column_stack([np.ones(e.size), t])
        (off, rate), *_ = np.linalg.lstsq(X[s:], e[s:], rcond=None)
        sse_lin = float(np.sum((e[s:] - X[s:] @ [off, rate]) ** 2))
        taus = np.geomspace(1.0, 300.0, 30)
        best = None
        for tau in taus:
            Xe = np.column_stack([np.ones(e.size), 1.0 - np.exp(-t / tau)])
            coef, *_ = np.linalg.lstsq(Xe[s:], e[s:], rcond=None)
            sse = float(np.sum((e[s:] - Xe[s:] @ coef) ** 2))
            if best is None or sse < best[0]:
                best = (sse, tau, coef)
        # a thermal drift approaches its end value: the exponential unless its time constant runs
        # to the grid's end (then it is a straight line over the record) or it fits no better
        interior = best is not None and taus[0] < best[1] < taus[-1]
        if interior and best[0] < sse_lin:
            _, tau, (off_e, amp) = best
            stage = ZeroDrift(ctx.fs, amplitude=float(amp), time_constant_s=float(tau), offset=float(off_e))
        else:
            stage = ZeroDrift(ctx.fs, rate_per_s=float(rate), offset=float(off))
        return Fitted(self.name, augment(base, output_stage=stage), stage.params())

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        return coef_departure(tests["slow_trend"], fp, "offset drift", "/s") if fp else \
            no_print(tests["slow_trend"].detail)

    def n_params(self, params: Mapping[str, Any]) -> int:
        """offset and rate, or offset, amplitude and time constant."""
        return 2 if "rate_per_s" in params else 3

    def observer_form(self, params: dict[str, Any], fs_hz: float) -> None:
        """No states of its own: the random-walk bias state covers the effect (a drift)."""
        return None

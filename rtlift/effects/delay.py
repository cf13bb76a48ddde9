"""The ``delay`` effect: measured lift lags the actuation record (DAQ or convective latency).

Fit: D = argmin_D ‖z(k) − ŷ(k − D)‖ over 1 … :data:`MAX_LAG` samples (the training residual's
lag search); evidence: that lag against the print's; stage :class:`rtlift.blocks.delay.Delay`.
"""

from __future__ import annotations

from rtlift.blocks.delay import Delay
from rtlift.core.records import Record
from rtlift.effects.base import Effect, no_print
from rtlift.effects.surgery import Context, Fitted, augment
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, lag_departure
from rtlift.residual.stats import TestResult

MAX_LAG = 100                      # samples the delay search reaches (0.25 s at 400 Hz)


class DelayEffect(Effect):
    """Cμ′(k) = Cμ(k − D), D = round(seconds · fs)."""

    name = Delay.name
    row = 10
    meaning = "measured lift lags the actuation record (DAQ or convective latency)"
    params = {"seconds": (0.025, 0.005, 0.1, "s")}
    path = "input"
    stages = (Delay,)
    spent = 1

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        d = int(ctx.tests["lag"].data["lag"])
        if d == 0:
            return "the lag search finds the model in step with the measurement"
        stage = Delay(d / ctx.fs, ctx.fs)
        bound = f"the lag search ended at its largest lag ({MAX_LAG} samples)" if d >= MAX_LAG else ""
        return Fitted(self.name, augment(base, input_stage=stage), stage.params(), on_bound=bound)

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        d = int(round(fitted.params["seconds"] * fitted.model.fs_hz))
        return lag_departure(tests["lag"], fp, d) if fp else no_print(f"lag {d} samples")

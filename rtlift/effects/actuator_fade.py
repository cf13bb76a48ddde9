"""The ``actuator_fade`` effect: actuators deliver less Cμ as they heat up over accumulated burst on-time.

Fit: (f, τ) by Levenberg–Marquardt on the full augmented model, for both clocks (burst on-time:
heating by actuation; wall time), the better kept. The clock starts at the record's start at
:data:`ON_TIME0_META`'s value for that clock (0 without it): a window of a run whose fade had been
running (``--adapt`` fitting it again) says how long. Evidence: the residual's gain drift against
the print's. Stage :class:`rtlift.blocks.actuator_fade.ActuatorFade`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy  # its submodules load on first use (scipy's lazy loader): not on a live start's path

from rtlift.blocks.actuator_fade import ActuatorFade
from rtlift.core.records import Record
from rtlift.effects.base import Effect, no_print
from rtlift.effects.surgery import Context, Fitted, at_bound, augment, predict
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, coef_departure
from rtlift.residual.stats import TestResult

ON_TIME0_META = {"on_time": "actuator_fade_on_time0_s", "time": "actuator_fade_time0_s"}
"""The record metadata giving the fade's clock at the record's start (s), per clock."""


def clock_at_start(train: Record, clock: str) -> float:
    """The fade's clock E₀ at ``train``'s start for ``clock`` (its metadata; 0 without it)."""
    try:
        return max(0.0, float(train.meta.get(ON_TIME0_META[clock], 0.0)))
    except (TypeError, ValueError):
        return 0.0


class ActuatorFadeEffect(Effect):
    """g(k) = f + (1 − f) exp(−E(k)/τ) on Cμ and Cμ_env, E the burst on-time (or wall time)."""

    name = ActuatorFade.name
    row = 30
    meaning = "actuators deliver less Cμ as they heat up over accumulated burst on-time"
    params = {"final_fraction": (0.6, 0.4, 0.9, "1"), "time_constant_s": (3.0, 1.0, 10.0, "s")}
    path = "input"
    stages = (ActuatorFade,)
    spent = 2

    def fit(self, base: HybridModel, train: Record, ctx: Context) -> Fitted | str:
        z = train.dcl[ctx.start:]
        lo_tau, hi_tau = 0.05, 500.0
        fits: dict[str, Any] = {}
        for clock in ActuatorFade.CLOCKS:
            model = augment(base, input_stage=ActuatorFade(1.0, 1.0, ctx.fs, clock, clock_at_start(train, clock)))
            stage = next(s for s in model.input_stages if type(s) is ActuatorFade)

            def resid(theta: np.ndarray, stage: ActuatorFade = stage, model: HybridModel = model) -> np.ndarray:
                stage.final_fraction = float(np.clip(theta[0], 0.0, 1.0))
                stage.time_constant_s = float(np.exp(theta[1]))
                return z - predict(model, train).total[ctx.start:]

            scale = 1.0 if clock == "time" else 0.1        # burst on-time runs at the duty cycle
            for f0, tau0 in ((0.6, 3.0), (0.85, 8.0), (0.4, 1.0)):
                res = scipy.optimize.least_squares(resid, [f0, math.log(tau0 * scale)],
                                             bounds=([0.0, math.log(lo_tau)], [1.0, math.log(hi_tau)]),
                                             x_scale=[0.1, 0.5], max_nfev=60)
                if clock not in fits or res.cost < fits[clock].cost:
                    fits[clock] = res
        # with bursts at a fixed period the two clocks are proportional: heating by actuation (the
        # burst on-time) stays unless the wall clock fits the training record clearly better
        clock = "time" if fits["time"].cost < 0.98 * fits["on_time"].cost else "on_time"
        res = fits[clock]
        stage = ActuatorFade(float(res.x[0]), float(math.exp(res.x[1])), ctx.fs, clock, clock_at_start(train, clock))
        bound = at_bound(stage.final_fraction, 0.0, 1.0, "final_fraction") or \
            at_bound(math.log(stage.time_constant_s), math.log(lo_tau), math.log(hi_tau), "log time_constant_s")
        return Fitted(self.name, augment(base, input_stage=stage), stage.params(), on_bound=bound)

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        return coef_departure(tests["gain_trend"], fp, "gain drift", "/s") if fp else \
            no_print(tests["gain_trend"].detail)

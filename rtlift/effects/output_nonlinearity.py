"""The ``output_nonlinearity`` effect: the static nonlinearity acts on y (textbook Wiener) rather than on Cμ.

Fit: f(y) as a piecewise-linear table on 10 quantile knots of y, node values by
ridge-regularised linear LS of the output error (paper form only). Evidence: the residual's
level dependence against the print's. The Wiener nonlinearity form
:class:`~rtlift.blocks.wiener.OutputNonlinearity`.
"""

from __future__ import annotations

import numpy as np

from rtlift.blocks.wiener import InputGain, OutputNonlinearity
from rtlift.core.records import Record
from rtlift.effects.base import Effect, no_print
from rtlift.effects.hysteresis import HysteresisEffect
from rtlift.effects.surgery import Context, Fitted, augment, output_sse, predict, wiener_parts
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, level_departure
from rtlift.residual.stats import TestResult


class OutputNonlinearityEffect(Effect):
    """ΔCL_L = f(y) instead of N(Cμ)·y."""

    name = "output_nonlinearity"
    row = 70
    meaning = "the static nonlinearity acts on y (textbook Wiener) rather than on Cμ"
    path = "nonlinearity"
    stages = (OutputNonlinearity,)
    spent = 10
    excludes = (HysteresisEffect.name,)
    fits_change = True

    def fit(self, base: HybridModel, train: Record, ctx: Context,
                                knots: int = 10, ridge: float = 1e-3) -> Fitted | str:
        """Textbook Wiener: f(y) instead of N(Cμ)·y. The LTI is re-identified by output-error PEM
        with f = the model's own static map (Cμ ↦ N(Cμ)·Cμ), then f's node values are refined by
        linear LS on quantile knots of the new y; the better of the two on training is kept."""
        from rtlift.identify.pem import fit_wiener

        nl = base.wiener.nonlinearity
        if type(nl) is not InputGain:
            return f"the Wiener nonlinearity is already '{nl.form}'"
        if base.output_stages and any(st.kind == "filter" for st in base.output_stages):
            return "not tried behind a filter stage"
        s = ctx.start
        out = predict(base, train)
        env, _ = wiener_parts(base, train)
        z = train.dcl - out.total + out.low                 # what the Wiener part must explain
        grid, fmap = nl.cmu, nl.gain * nl.cmu
        try:
            pem = fit_wiener(env, z, base.wiener.lti.n, form="output_map", fs_hz=ctx.fs,
                             table=(grid, fmap), skip=s, n_starts=1, max_nfev=200)
        except (ValueError, np.linalg.LinAlgError) as exc:
            return f"PEM with f(y) failed ({exc})"
        lti = (pem.lti.A, pem.lti.B, pem.lti.C)
        first = augment(base, nonlinearity=OutputNonlinearity(grid, fmap), lti=lti)
        _, y = wiener_parts(first, train)
        knots_y = np.unique(np.quantile(y[s:], np.linspace(0, 1, knots)))
        best = first
        if knots_y.size >= 3:
            cols = []
            for i in range(knots_y.size):
                unit = np.zeros(knots_y.size)
                unit[i] = 1.0
                cols.append(OutputNonlinearity(knots_y, unit).simulate(env, y))
            Phi = np.column_stack(cols)[s:]
            D2 = np.diff(np.eye(knots_y.size), 2, axis=0)
            A = np.vstack([Phi, ridge * float(np.linalg.norm(Phi, 2)) * D2])
            v, *_ = np.linalg.lstsq(A, np.concatenate([z[s:], np.zeros(D2.shape[0])]), rcond=None)
            refined = augment(base, nonlinearity=OutputNonlinearity(knots_y, v), lti=lti)
            if output_sse(refined, train, s) < output_sse(first, train, s):
                best = refined
        return Fitted(self.name, best,
                      {"form": OutputNonlinearity.form, "knots": int(best.wiener.nonlinearity.y.size)})

    def evidence(self, tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
        return level_departure(tests["level"], fp) if fp else no_print(tests["level"].detail)

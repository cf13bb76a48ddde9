"""A single-input model's state at a record's start, estimated from the record's first samples.

A benchmark's test record need not start at rest (Cascaded Tanks' records start with water in
the tanks); its rules leave the first ``STATE_INIT_SAMPLES`` unscored as a state-initialisation
window. :func:`initial_state` takes the system to have been at rest at a constant input ū before
the record (a steady state of the model's own, so a state it can be in) and picks ū so that the
free-run output best fits the window's measured output (least squares over ``GRID`` levels from
half the record's input range below its least input to as far above its greatest, then a bounded
scalar search about the best: the input before the record may have been beyond it); rest itself
(the model's zero state) is kept when it fits better. Only the window's outputs are used. A free
fit of the whole state vector to the window was tried first: on a Wiener model it fitted the
window and ran off after it (Cascaded Tanks' test error 1.4 → 2.6 V), a steady state cannot.
The model is not changed; the free run from that state is its own :meth:`simulate` (streaming
and batch alike).

A model whose state is its own recent outputs and map values (a ``nonlinear_feedback`` model,
:class:`~rtlift.model.siso.FeedbackModel`, neither integrating nor limited: x = [y(k−1) … y(k−n),
v(k−1) … v(k−n)]) is not left at a steady state: its whole state is then refined by least squares
on the window, min_x Σ_{k<n} (ŷ(k; x) − y(k))² (Levenberg–Marquardt from the best steady state),
where the window has at least as many samples as the state has entries. A system in the middle of
an excitation (a multisine's period, not a rest at a constant input) is in no steady state: on
Silverbox's estimation data, 1074-sample windows of its held-out 20 % scored as a test is (50
samples to estimate the state, 1024 scored) erred 0.86 mV from the steady state, most of it in
the first 200 samples (a lightly damped resonance's start-up), and 0.27 mV from the refined state
— the long free run's own error on the same samples (0.30 mV). A limited model is left out (at
its limit the output says nothing of the state), as is a Wiener model (the free fit that ran off
on Cascaded Tanks, above).


A model whose output is a running sum (an integrating ``nonlinear_feedback`` model: a position
from a velocity; its ``accumulator`` names the sum's place in the state) was not at rest at a
position of zero before the record, and no constant input holds it still: for every candidate
state the sum is set to the mean of the window's output less the free run from a sum of zero
(the output shifts one for one with it, so that is its least-squares value), the velocity's
state still the steady state's.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from rtlift.model.siso import FeedbackModel

SETTLE_SAMPLES = 20000
"""Samples of a constant input a model runs from rest to reach its steady state."""
GRID = 31
"""Input levels tried before the scalar search."""


def steady_state(model, level: float) -> np.ndarray:
    """The state the model settles at under the constant input ``level`` (left reset)."""
    model.reset()
    with np.errstate(all="ignore"):
        model.simulate(np.full(SETTLE_SAMPLES, float(level)))
    x = model.get_state()
    model.reset()
    return x


def initial_state(model, u: np.ndarray, y: np.ndarray, n: int) -> np.ndarray:
    """The state at sample 0 that best explains y[:n] (module docstring); the model is left reset."""
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    uw, yw = u[:n], y[:n]
    acc = getattr(model, "accumulator", None)

    def run(x: np.ndarray) -> np.ndarray:
        model.reset()
        model.set_state(x)
        with np.errstate(all="ignore"):
            r = model.simulate(uw) - yw
        model.reset()
        return r

    def placed(x: np.ndarray) -> np.ndarray:
        """x with the running sum at its least-squares value (module docstring)."""
        if acc is None:
            return x
        x = np.array(x, dtype=float)
        x[acc] = 0.0
        x[acc] = -float(np.mean(run(x)))
        return x if np.isfinite(x[acc]) else np.where(np.arange(x.size) == acc, 0.0, x)

    def cost(x: np.ndarray) -> float:
        r = run(x)
        with np.errstate(all="ignore"):
            c = float(r @ r)
        return c if np.isfinite(c) else np.inf

    def steady(level: float) -> np.ndarray:
        return placed(steady_state(model, level))

    model.reset()
    rest = placed(model.get_state())
    best = (cost(rest), rest)
    span = float(np.ptp(u))
    lo, hi = float(np.min(u)) - 0.5 * span, float(np.max(u)) + 0.5 * span
    if hi > lo:
        levels = np.linspace(lo, hi, GRID)
        costs = [cost(steady(v)) for v in levels]
        i = int(np.argmin(costs))
        a, b = levels[max(i - 1, 0)], levels[min(i + 1, GRID - 1)]
        sol = optimize.minimize_scalar(lambda v: cost(steady(v)), bounds=(a, b), method="bounded",
                                       options={"xatol": 1e-6 * (hi - lo)})
        for c, v in ((costs[i], levels[i]), (float(sol.fun), float(sol.x))):
            if c < best[0]:
                best = (c, steady(v))
    x = np.asarray(best[1], dtype=float)
    if isinstance(model, FeedbackModel) and not (model.integrating or model.limited) and uw.size >= x.size \
            and np.isfinite(best[0]):
        with np.errstate(all="ignore"):
            try:
                fit = optimize.least_squares(run, x, method="lm", x_scale="jac").x
            except ValueError:          # residuals that turn non-finite on the way
                fit = x
        if np.all(np.isfinite(fit)) and cost(fit) < best[0]:
            x = fit
    model.reset()
    return x

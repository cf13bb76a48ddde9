"""Identify the ``nonlinear_feedback`` model (:class:`rtlift.model.siso.FeedbackModel`) for
:func:`rtlift.sysid.identify.identify_siso`: for each order in ``feedback_orders`` an ARX
least-squares fit is the start, and the linear block's coefficients, the feedthrough, the
feedback's two coefficients and the output's offset are refined together by Levenberg–Marquardt
on the simulation error; the order with the lowest held-out RMSE is kept.

With a limit (``limits=(lower, upper)``) where ``output``, every refinement cost is the clipped
model's simulation error (:mod:`rtlift.sysid.identify`, 4). With ``where="state"`` the limit acts
inside the recursion (``FeedbackModel.state_limits``): the model's output sits at the limit
exactly while the store is full, so every sample is fitted, none censored.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from rtlift.model.siso import FeedbackModel, SaturatedModel
from rtlift.sysid.common import NO_LIMITS, Limits, SisoOptions, _limited, _rmse


def identify_feedback(u: np.ndarray, y: np.ndarray, u_all: np.ndarray, y_all: np.ndarray, n_est: int,
                      skip: int, fs: float, opt: SisoOptions, limits: Limits = NO_LIMITS,
                      where: str = "output") -> FeedbackModel | SaturatedModel:
    """The ``nonlinear_feedback`` model (module docstring): fitted on (u, y), order chosen by the
    held-out RMSE of (u_all, y_all) from ``n_est`` on; ``limits`` on its output or its state. The
    output's offset (the operating point the map is centred on) is refined with the rest: Silverbox's
    input has a mean of 6 mV, and a cubic about the sensor's zero instead of the spring's rest
    position nearly doubled the held-out error."""
    inner = limits if where == "state" else NO_LIMITS     # the limit inside the recursion
    outer = NO_LIMITS if where == "state" else limits     # the clip after it
    best = None
    for n in opt.feedback_orders:
        rows = np.arange(n, u.size)
        X = np.column_stack([-y[rows - i] for i in range(1, n + 1)] + [u[rows - i] for i in range(0, n + 1)])
        th, *_ = np.linalg.lstsq(X, y[rows], rcond=None)
        th = np.concatenate([th[:n], th[n + 1:], [th[n]]])          # [a, b₁…bₙ, b₀]

        def build(p: np.ndarray, n: int = n) -> FeedbackModel:
            return FeedbackModel(p[:n], p[n:2 * n], p[2 * n + 1:2 * n + 3], fs, state_limits=inner, offset=p[-1],
                                 feedthrough=p[2 * n])

        def res(p: np.ndarray) -> np.ndarray:
            with np.errstate(all="ignore"):
                r = (np.clip(build(p).simulate(u), *outer) - y)[skip:]
            return r if np.all(np.isfinite(r)) else np.full(r.size, 1e3)

        sol = optimize.least_squares(res, np.concatenate([th, [0.0, 0.0, 0.0]]), method="lm", x_scale="jac",
                                     max_nfev=opt.max_nfev, ftol=1e-13, xtol=1e-13)
        model = _limited(build(sol.x), outer)
        with np.errstate(all="ignore"):
            held = _rmse(model, u_all, y_all, n_est)
        if np.isfinite(held) and (best is None or held < best[0]):
            best = (held, model, n)
    if best is None:
        raise ValueError("no stable nonlinear-feedback model found")
    held, model, n = best
    model.provenance = {"structure": "nonlinear_feedback", "order": n}
    model.metrics = {"holdout_rmse": held}
    return model

"""Identify the ``store_chain`` model for :func:`rtlift.sysid.identify.identify_siso`.

**Store chain** (``structure="store_chain"``, :class:`.model.StoreChainModel`): two stores in
cascade with power-law outflows. Its parameters enter nonlinearly and the simulation error
has many local minima (a store that drains too fast or never fills is a flat valley), so it
is refined by bounded least squares from ``chain_starts`` starts: exponents ½ (Torricelli),
the offset c at the record's 1 % level (the empty lower store), the stores' time constants
drawn log-uniformly between 2 samples and a third of the record (a fixed seed), each store's
outflow coefficient set so that, linearised about the mean level, it has that time constant,
and inflow and transfer so that the mean input holds both stores at that level. The stores'
levels at the record's start are refined with the rest (started with the lower store at the
first measured level, the upper one in equilibrium with it): a record need not start with
the stores empty (Cascaded Tanks' do not). The start with the lowest held-out RMSE (the run
from those levels) is kept. Positive parameters are refined in logarithms. With a limit
(``where="state"``, the only place a store chain takes one) the lower store is full at the
output's limit (``ceiling`` = upper); the upper store's brim and spill share are fitted.
"""

from __future__ import annotations

import math

import numpy as np

from rtlift.model.siso import StoreChainModel
from rtlift.sysid.common import NO_LIMITS, Limits, SisoOptions
from rtlift.sysid.parallel import least_squares


def identify_store_chain(u: np.ndarray, y: np.ndarray, u_all: np.ndarray, y_all: np.ndarray, n_est: int,
                         skip: int, fs: float, opt: SisoOptions, limits: Limits = NO_LIMITS) -> StoreChainModel:
    """The ``store_chain`` model (module docstring): fitted on (u, y) from rest, the start kept
    by the held-out RMSE of (u_all, y_all) from ``n_est`` on; ``limits``' upper side is the lower
    store's brim as an output level."""
    u_mean = float(np.mean(u))
    if not u_mean > 0:
        raise ValueError("a store chain needs an input of positive mean (a pump's flow)")
    upper = float(limits[1])
    c0 = float(np.quantile(y, 0.01))
    level = float(np.mean(y)) - c0
    if not level > 0:
        raise ValueError("a store chain needs an output above its empty level")
    rng = np.random.default_rng(0)
    n = u.size

    limited = bool(np.isfinite(upper))

    def unpack(th: np.ndarray) -> dict[str, float]:
        b, a1, p1, r, a2, p2, c = th[:7]
        l1, beta = (math.exp(th[7]), th[8]) if limited else (np.inf, 0.0)
        return {"inflow": math.exp(b), "outflow_1": math.exp(a1), "exponent_1": p1, "transfer": math.exp(r),
                "outflow_2": math.exp(a2), "exponent_2": p2, "brim_1": l1,
                "ceiling": upper if limited else np.inf, "spill": beta, "offset": c}

    npar = 9 if limited else 7

    def start(th: np.ndarray) -> np.ndarray:
        """The stores' levels at the record's start: logarithms of the last two entries."""
        return np.exp(th[npar:])

    def res(th: np.ndarray) -> np.ndarray:
        try:
            m = StoreChainModel(unpack(th), fs)
            m.set_state(start(th))
        except (ValueError, OverflowError):
            return np.full(n - skip, 1e3 * level)
        with np.errstate(all="ignore"):
            r = (m.simulate(u) - y)[skip:]
        return r if np.all(np.isfinite(r)) else np.full(r.size, 1e3 * level)

    def held_out(model: StoreChainModel, x0: np.ndarray) -> float:
        model.reset()
        model.set_state(x0)
        with np.errstate(all="ignore"):
            out = model.simulate(u_all)
        model.reset()
        return float(np.sqrt(np.mean((out - y_all)[n_est:] ** 2)))

    c_hi = upper - 1e-6 * level if limited else np.inf
    lo = np.array([-40, -40, 0.1, -40, -40, 0.1, -np.inf, -40, 0.0][:npar] + [-40.0, -40.0])
    hi = np.array([40, 40, 2.0, 40, 40, 2.0, c_hi, 40, 100.0][:npar] + [40.0, 40.0])
    best = None
    for _ in range(opt.chain_starts):
        t1, t2 = np.exp(rng.uniform(np.log(2.0), np.log(max(3.0, n / 3.0)), 2)) / fs
        x1 = x2 = level
        a1, a2 = 2.0 * x1**0.5 / t1, 2.0 * x2**0.5 / t2            # x^(1−p)/(p τ), p = ½
        b = a1 * x1**0.5 / u_mean
        r = a2 * x2**0.5 / (a1 * x1**0.5)
        brim = math.log(3.0 * x1) + rng.normal(0.0, 0.3)
        c = min(c0, c_hi - 1e-6 * level)
        # the record's start: the lower store at the first measured level, the upper one at the
        # level that feeds it as much as it drains (in equilibrium)
        x2 = min(max(float(y[0]) - c, 1e-3 * level), c_hi - c)
        x1 = (a2 * x2**0.5 / (r * a1)) ** 2
        th0 = np.array([math.log(b), math.log(a1), 0.5, math.log(r), math.log(a2), 0.5, c, brim, 0.3][:npar]
                       + [math.log(x1), math.log(x2)])
        th0 = np.clip(th0, lo + 1e-9, hi - 1e-9)
        sol = least_squares(res, th0, n - skip, bounds=(lo, hi), x_scale="jac", max_nfev=opt.max_nfev)
        model = StoreChainModel(unpack(sol.x), fs)
        held = held_out(model, start(sol.x))
        if np.isfinite(held) and (best is None or held < best[0]):
            best = (held, model, start(sol.x))
    if best is None:
        raise ValueError("no store chain fits the record")
    held, model, x0 = best
    model.provenance = {"structure": "store_chain", "starts": opt.chain_starts,
                        "initial_state": [float(v) for v in x0]}
    model.metrics = {"holdout_rmse": held}
    return model

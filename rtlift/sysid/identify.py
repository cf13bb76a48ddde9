"""Identify a single-input W-block model (:mod:`.model`) from one generic record.

1. **Best linear approximation** (BLA): an output-error model y ≈ B(q)/A(q) u of order n
   (Ljung eq. 7.12), started from ARX least squares, refined by Levenberg–Marquardt with the
   stable second-order-section parametrisation of :mod:`rtlift.identify.poles`; n chosen from
   ``orders`` by the held-out RMSE of the record's last ``holdout`` fraction.
2. **Wiener** (``structure="wiener"``): G₁ = the BLA at unit DC gain, f piecewise linear on
   ``knots`` quantile knots of x = G₁u; f's values enter linearly, so for every G₁ they are
   eliminated by least squares (variable projection, Golub & Pereyra 1973) and G₁'s poles and
   zeros are refined jointly on the simulation error. Then, for each count in ``more_knots``,
   the best model's f is put on that many quantile knots and everything is refined jointly
   again from there, kept only if the held-out RMSE falls (WH2009: 16 knots 0.54 mV held out,
   48 then 96 knots 0.27 mV; refining on 32 knots from the start instead took 4× as long), each
   refinement at most ``more_knots_nfev`` evaluations (WH2009's converge within them; Silverbox's
   Wiener model crawled through 400 on 96 knots for a gain of 0.1 %).
3. **Wiener–Hammerstein** (``output_dynamics``): the BLA's poles and zeros (complex pairs kept
   together) are split every way between G₁ and G₂ (G_i at unit DC gain); for each split f is
   fitted by linear least squares (y ≈ Σ_j c_j G₂(φ_j(x)), φ_j the knots' hat functions);
   the ``keep`` best splits are refined jointly (G₁, G₂, f) on simulation error and the one
   with the lowest held-out RMSE is kept (M. Schoukens, Pintelon & Rolain 2014 initialise the
   same way from a nonparametric BLA).

4. **Saturation** (``limits=(lower, upper)``, the ``saturation`` structure on any structure):
   the output is clipped at the limits, y = min(max(M(u), lower), upper). Samples measured at
   a limit are censored: they say only that M's output is at or beyond it, so f's values are
   fitted on the other samples, and every refinement cost is the simulation error of the
   clipped model, min(max(ŷ, lower), upper) − y, which for a censored sample is nonzero only
   while ŷ has not reached the limit (the censored least squares of a Tobit model).
   With ``where="state"`` the limit acts inside the model instead (nonlinear feedback:
   :mod:`.feedback`; a store chain: :mod:`.store_chain`).

Refinement costs are evaluated on at most ``cost_samples`` samples of the estimation part
(simulation over them, from rest; the first ``skip`` samples left out as the initial state is
unknown); f is refitted on the whole estimation part at the end.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import linalg, optimize, signal

from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import OutputNonlinearity
from rtlift.core.records import SisoRecord
from rtlift.core.threads import one_blas_thread
from rtlift.identify.poles import denominator_from_theta, theta_from_poles
from rtlift.model.siso import LIMITED, STRUCTURES, SaturatedModel, SisoModel, listed
from rtlift.sysid.common import NO_LIMITS, Limits, SisoOptions, _limited, _rmse
from rtlift.sysid.feedback import identify_feedback
from rtlift.sysid.store_chain import identify_store_chain


def _hats(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Φ[k, j] = φ_j(x(k)): the piecewise-linear basis of f on ``knots`` (f = Φ c), extrapolated
    linearly beyond the ends (as :class:`OutputNonlinearity` evaluates it). Each row has two
    nonzero entries, those of x(k)'s segment s, [1 − (x − x_s)/h_s, (x − x_s)/h_s], written
    with the same operations :class:`OutputNonlinearity` applies to a unit table (bit for bit
    the same basis, one search instead of one per knot)."""
    x = np.asarray(x, dtype=float)
    knots = np.asarray(knots, dtype=float)
    last = knots.size - 1
    inv = 1.0 / np.diff(knots)
    seg = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, last - 1)
    above = x >= knots[-1]
    d = np.where(above, x - knots[-1], x - knots[seg])
    rows = np.arange(x.size)
    phi = np.zeros((x.size, knots.size), order="F")    # column-major: G₂ filters it column by column
    phi[rows, seg] = np.where(above, -inv[seg] * d + 0.0, -inv[seg] * d + 1.0)
    phi[rows, seg + 1] = np.where(above, inv[seg] * d + 1.0, inv[seg] * d + 0.0)
    phi[x == knots[-1], last - 1] = 0.0
    phi[x == knots[-1], last] = 1.0
    return phi


def _unit_dc(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    g = np.sum(b) / np.sum(a)
    return b / g if abs(g) > 1e-12 else b


@dataclass
class _Dims:
    """Sizes of θ = [G₁ denominator θ, G₁ numerator b₁[1:]/b₁[0], same for G₂]."""

    n1: int
    m1: int
    n2: int
    m2: int

    def build(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        i = 0
        a1 = np.concatenate([[1.0], denominator_from_theta(th[i:i + self.n1], self.n1)]) if self.n1 else np.ones(1)
        i += self.n1
        b1 = np.concatenate([[1.0], th[i:i + self.m1]])
        i += self.m1
        if self.n2 + self.m2 == 0:
            return _unit_dc(b1, a1), a1, None, None
        a2 = np.concatenate([[1.0], denominator_from_theta(th[i:i + self.n2], self.n2)]) if self.n2 else np.ones(1)
        i += self.n2
        b2 = np.concatenate([[1.0], th[i:i + self.m2]])
        return _unit_dc(b1, a1), a1, _unit_dc(b2, a2), a2

    @staticmethod
    def theta(b1, a1, b2, a2) -> np.ndarray:
        parts = [theta_from_poles(np.roots(a1)) if a1.size > 1 else np.empty(0), b1[1:] / b1[0]]
        if b2 is not None:
            parts += [theta_from_poles(np.roots(a2)) if a2.size > 1 else np.empty(0), b2[1:] / b2[0]]
        return np.concatenate(parts)


def _simulate_basis(dims: _Dims, th: np.ndarray, u: np.ndarray, count: int):
    """Φ of ``count`` knots at x's quantiles, filtered by G₂ (if any), and the knots."""
    b1, a1, b2, a2 = dims.build(th)
    x = signal.lfilter(b1, a1, u)
    knots = np.unique(np.quantile(x, np.linspace(0.002, 0.998, count)))
    phi = _hats(x, knots)
    if b2 is not None:
        # column by column in Fortran order: the same numbers as on the row-major array, in half the time
        phi = signal.lfilter(b2, a2, np.asfortranarray(phi), axis=0)
    return phi, knots


def _uncensored(y: np.ndarray, limits: Limits) -> np.ndarray:
    """Samples not measured at a limit (module docstring, 4)."""
    lo, hi = limits
    tol = 1e-9 * max(float(np.ptp(y)), 1e-300)
    return (y > lo + tol) & (y < hi - tol)


def _fit_values(phi: np.ndarray, y: np.ndarray, skip: int, limits: Limits = NO_LIMITS) -> np.ndarray:
    """f's values c minimising ‖Φc − y‖ over the uncensored samples from ``skip`` on. By the
    normal equations (Cholesky of the column-scaled ΦᵀΦ, a few knots' columns, well conditioned
    as hat functions are): the refinements solve this thousands of times on tens of thousands of
    rows, where LAPACK's SVD-based least squares costs ~10× more (and ~100× on a loaded 2-core
    machine, its threads contending). Falls back to that least squares when ΦᵀΦ is not
    positive definite to working precision (a knot no sample reaches)."""
    if limits == NO_LIMITS:
        a, b = phi[skip:], y[skip:]                      # views: no sample is censored
    else:
        keep = _uncensored(y, limits)
        keep[:skip] = False
        a, b = phi[keep], y[keep]
    g = a.T @ a
    scale = np.sqrt(np.diag(g))
    if np.all(scale > 0):
        gs = g / np.outer(scale, scale)
        try:
            cf = linalg.cho_factor(gs, check_finite=False)
            if np.min(np.abs(np.diag(cf[0]))) ** 2 > 1e-10:
                return linalg.cho_solve(cf, (a.T @ b) / scale, check_finite=False) / scale
        except linalg.LinAlgError:
            pass
    c, *_ = np.linalg.lstsq(a, b, rcond=None)
    return c


def fit_bla(u: np.ndarray, y: np.ndarray, n: int, skip: int, max_nfev: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Output-error linear model of order n (numerator n + 1 taps): (b, a)."""
    rows = np.arange(n, u.size)
    X = np.column_stack([-y[rows - k] for k in range(1, n + 1)] + [u[rows - k] for k in range(n + 1)])
    th, *_ = np.linalg.lstsq(X, y[rows], rcond=None)
    a0 = np.concatenate([[1.0], th[:n]])
    a0 = np.poly(np.clip(np.abs(np.roots(a0)), 0, 0.995) * np.exp(1j * np.angle(np.roots(a0)))).real
    b0 = th[n:]

    def res(p: np.ndarray) -> np.ndarray:
        a = np.concatenate([[1.0], denominator_from_theta(p[:n], n)])
        return (signal.lfilter(p[n:], a, u) - y)[skip:]

    sol = optimize.least_squares(res, np.concatenate([theta_from_poles(np.roots(a0)), b0]), x_scale="jac",
                                 max_nfev=max_nfev)
    return sol.x[n:], np.concatenate([[1.0], denominator_from_theta(sol.x[:n], n)])


def _groups(roots: np.ndarray) -> list[np.ndarray]:
    """Roots grouped as complex-conjugate pairs and single reals."""
    left = list(roots)
    out = []
    while left:
        r = left.pop(0)
        if abs(r.imag) > 1e-9 and left:
            j = int(np.argmin([abs(v - np.conj(r)) for v in left]))
            out.append(np.array([r, left.pop(j)]))
        else:
            out.append(np.array([r.real]))
    return out


def _splits(b: np.ndarray, a: np.ndarray):
    """Every split of the BLA's pole groups and zero groups between G₁ and G₂ (G₂ non-trivial)."""
    pg, zg = _groups(np.roots(a)), _groups(np.roots(b))
    for pm in itertools.product((0, 1), repeat=len(pg)):
        for zm in itertools.product((0, 1), repeat=len(zg)):
            if not any(pm) and not any(zm):
                continue
            p1 = np.concatenate([g for g, m in zip(pg, pm, strict=True) if not m] or [np.empty(0)])
            p2 = np.concatenate([g for g, m in zip(pg, pm, strict=True) if m] or [np.empty(0)])
            z1 = np.concatenate([g for g, m in zip(zg, zm, strict=True) if not m] or [np.empty(0)])
            z2 = np.concatenate([g for g, m in zip(zg, zm, strict=True) if m] or [np.empty(0)])
            yield tuple(np.real(np.poly(r)) if r.size else np.ones(1) for r in (z1, p1, z2, p2))


def _refine(dims: _Dims, th0: np.ndarray, u: np.ndarray, y: np.ndarray, skip: int, max_nfev: int,
            knots: int, limits: Limits = NO_LIMITS) -> np.ndarray:
    def res(th: np.ndarray) -> np.ndarray:
        phi, _ = _simulate_basis(dims, th, u, knots)
        r = (np.clip(phi @ _fit_values(phi, y, skip, limits), *limits) - y)[skip:]
        return r if np.all(np.isfinite(r)) else np.full(r.size, 1e3)

    return optimize.least_squares(res, th0, x_scale="jac", max_nfev=max_nfev, ftol=1e-10, xtol=1e-10).x


def _model(dims: _Dims, th: np.ndarray, u: np.ndarray, y: np.ndarray, skip: int, fs: float, count: int,
           limits: Limits = NO_LIMITS) -> SisoModel | SaturatedModel:
    phi, knots = _simulate_basis(dims, th, u, count)
    c = _fit_values(phi, y, skip, limits)
    b1, a1, b2, a2 = dims.build(th)
    g2 = None if b2 is None else HighPassFilter.from_ba(b2, a2)
    return _limited(SisoModel(HighPassFilter.from_ba(b1, a1), OutputNonlinearity(knots, c), g2, fs), limits)


@one_blas_thread
def identify_siso(rec: SisoRecord, structure: str = "wiener", order: int | None = None,
                  options: SisoOptions | None = None, limits: Limits = NO_LIMITS,
                  where: str = "output") -> SisoModel:
    """The model of ``structure`` for one record (module docstring), its output (or, for
    nonlinear feedback, its state) clipped at ``limits`` if given (4); ValueError on unusable data."""
    opt = options or SisoOptions()
    if structure not in STRUCTURES:
        raise ValueError(f"unknown structure {structure!r}; expected one of {', '.join(STRUCTURES)}")
    if not (structure in LIMITED.get(where, ()) or where == "output" and limits == NO_LIMITS):
        raise ValueError(f"a limit where {where!r} is built for the output of {listed(LIMITED['output'])} and "
                         f"for the state of {listed(LIMITED['state'])}")
    u, y, fs = rec.u, rec.y, rec.fs_hz
    n_est = int(round((1.0 - opt.holdout) * u.size))
    skip = min(opt.skip, n_est // 10)
    if n_est - skip < 200 or u.size - n_est < 50:
        raise ValueError(f"record too short ({u.size} samples)")
    ue, ye = u[:n_est], y[:n_est]
    cost = slice(0, min(n_est, opt.cost_samples))
    if structure == "store_chain":
        model = identify_store_chain(ue[cost], ye[cost], u, y, n_est, skip, fs, opt, limits)
        model.provenance.update(tool="rtlift identify --record", record=rec.name, holdout_fraction=opt.holdout)
        model.metrics["train_rmse"] = _rmse(model, ue, ye, skip)
        return model
    if structure == "nonlinear_feedback":
        model = identify_feedback(ue[cost], ye[cost], u, y, n_est, skip, fs, opt, limits, where)
        model.provenance.update(tool="rtlift identify --record", record=rec.name, holdout_fraction=opt.holdout)
        model.metrics["train_rmse"] = _rmse(model, ue, ye, skip)
        return model
    orders = (order,) if order else opt.orders
    bla = {}
    for n in orders:
        b, a = fit_bla(ue[cost], ye[cost], n, skip)
        lin = SisoModel(HighPassFilter.from_ba(b, a), OutputNonlinearity([0.0, 1.0], [0.0, 1.0]), None, fs)
        bla[n] = (b, a, _rmse(lin, u, y, skip if n_est == 0 else n_est))
    n = min(bla, key=lambda k: bla[k][2])      # the split needs every pole the data supports
    b, a, bla_holdout = bla[n]
    if structure == "wiener":
        starts = [(_Dims(n, b.size - 1, 0, 0), (b, a, None, None))]
    else:
        starts = []
        for b1, a1, b2, a2 in _splits(b, a):
            dims = _Dims(a1.size - 1, b1.size - 1, a2.size - 1, b2.size - 1)
            if b1[0] == 0 or b2[0] == 0:
                continue
            th = _Dims.theta(b1, a1, b2, a2)
            phi, _ = _simulate_basis(dims, th, ue[cost], opt.knots)
            r = (np.clip(phi @ _fit_values(phi, ye[cost], skip, limits), *limits) - ye[cost])[skip:]
            starts.append((float(np.sum(r**2)), dims, (b1, a1, b2, a2)))
        starts = [(d, bb) for _, d, bb in sorted(starts, key=lambda s: s[0])[:opt.keep]]
    best = None
    for dims, (b1, a1, b2, a2) in starts:
        th = _refine(dims, _Dims.theta(b1, a1, b2, a2), ue[cost], ye[cost], skip, opt.max_nfev, opt.knots, limits)
        model = _model(dims, th, ue, ye, skip, fs, opt.knots, limits)
        held = _rmse(model, u, y, n_est)
        if best is None or held < best[0]:
            best = (held, model, dims, th, opt.knots)
    for count in opt.more_knots:      # the best one's f on finer knots, refined jointly again from there
        held0, _, dims, th0, _ = best
        th = _refine(dims, th0, ue[cost], ye[cost], skip, opt.more_knots_nfev, count, limits)
        model = _model(dims, th, ue, ye, skip, fs, count, limits)
        held = _rmse(model, u, y, n_est)
        if held < held0:
            best = (held, model, dims, th, count)
    held, model, _, _, knots = best
    model.provenance = {"tool": "rtlift identify --record", "record": rec.name, "structure": structure,
                        "bla_order": n, "bla_holdout_rmse": bla_holdout, "holdout_fraction": opt.holdout,
                        "splits_refined": len(starts), "knots": knots}
    model.metrics = {"holdout_rmse": held, "train_rmse": _rmse(model, ue, ye, skip)}
    return model

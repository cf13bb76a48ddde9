"""Identify a single-input W-block model (:mod:`.model`) from generic records: one, or several
experiments of one system (each its own run from rest, one cost pooled over them, each's last
``holdout`` fraction held out).

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

5. **Integrating outputs** (no limit): the BLA of every order is also fitted on the differenced
   output Δy(k) = y(k) − y(k − 1) (each run from rest), with a constant d (Δy ≈ B/A u + d: a
   force offset or a friction the input works against, a drift once integrated), and run
   integrated, y = Δŷ/(1 − q⁻¹) (the model fitted on y itself is left out where its linear model
   holds out no better than the mean and the integrating one does);
   where the best such linear model has the lower held-out RMSE, the W-block model is also
   fitted on Δy and closed by the integrator (G₂ = 1/(1 − q⁻¹), or G₂/(1 − q⁻¹)), and the one of
   the two with the lower held-out RMSE is kept. A pole at z = 1 in a model fitted on y itself
   is within the parametrisation's reach only to 1 − 10⁻⁷ and drifts over a long record.
   ``nonlinear_feedback`` has its own integrating variant, friction in the map fed back from the
   differenced output (:mod:`.feedback`), tried by the first-order linear models' rule
   (:func:`_integrating_start`).

6. **Multi-start** (``wiener``): where the best linear model holds out no better than the
   estimation data's mean (an even map such as |·| makes the BLA zero, and G₁ cannot be read
   from it), :data:`MULTI_STARTS` random stable G₁ are refined briefly besides it and the
   ``keep`` best by cost refined in full, at every order of :data:`BLIND_ORDERS` (the linear
   model's order is no guide either); the lowest held-out RMSE is kept. Asymmetric maps and
   dead zones need nothing more: f is piecewise linear on quantile knots, any shape.

An order, a split or a knot count whose fit fails numerically (a non-finite start, a constant
or non-finite G₁ output) is skipped and named in ``provenance["skipped"]``; on a short record the
orders and knot counts beyond :data:`PER_COEFFICIENT` samples per coefficient are not tried and
``provenance["notes"]`` says so.

Refinement costs are evaluated on at most ``cost_samples`` samples of the estimation part
(simulation over them, from rest; the first ``skip`` samples left out as the initial state is
unknown); f is refitted on the whole estimation part at the end.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg, signal

from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import OutputNonlinearity
from rtlift.core.records import SisoRecord, split_runs
from rtlift.core.threads import one_blas_thread
from rtlift.identify.poles import denominator_from_theta, theta_from_poles
from rtlift.model.siso import INTEGRATOR, LIMITED, STRUCTURES, SaturatedModel, SisoModel, listed
from rtlift.sysid.common import NO_LIMITS, Limits, SisoOptions, _limited, _pooled_rmse, _rmse
from rtlift.sysid.feedback import identify_feedback
from rtlift.sysid.kernels import Hats, lfilter
from rtlift.sysid.parallel import least_squares
from rtlift.sysid.store_chain import identify_store_chain


def _extrapolated_hat_basis(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Φ[k, j] = φ_j(x(k)): the piecewise-linear basis of f on ``knots`` (f = Φ c), extrapolated
    linearly beyond the ends (as :class:`OutputNonlinearity` evaluates it; the interaction
    structure's gains are held there instead, :func:`rtlift.identify.interaction._clamped_hat_basis`). Each row has two
    nonzero entries, those of x(k)'s segment s, [1 − (x − x_s)/h_s, (x − x_s)/h_s], written
    with the same operations :class:`OutputNonlinearity` applies to a unit table (bit for bit
    the same basis, one search instead of one per knot; compiled, :class:`.kernels.Hats`)."""
    return Hats(np.ascontiguousarray(x, dtype=float), np.asarray(knots, dtype=float)).basis()


def _unit_dc(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """b scaled to B(1)/A(1) = 1, the gain ambiguity's gauge (f carries the static gain). A block
    with a pole at z = 1 to working precision (A(1) within rounding of 0: an integrator, or poles
    pushed to the stability boundary) has no finite DC gain: b is returned as it is, the scale is
    f's (its values are refitted by least squares for every G₁, so the cost does not see the gauge).
    """
    sa = float(np.sum(a))
    if abs(sa) <= 1e-12 * float(np.sum(np.abs(a))):
        return b
    g = float(np.sum(b)) / sa
    return b / g if np.isfinite(g) and abs(g) > 1e-12 else b


class _Runs:
    """Records run one after another, each from rest, under one cost: u and y concatenated,
    ``bounds`` the first sample of each run and the end, the first ``skip`` samples of each run
    unscored (its unknown initial state). One run: exactly the single-record arithmetic."""

    def __init__(self, parts: list[tuple[np.ndarray, np.ndarray]], skip: int) -> None:
        self.u = np.concatenate([u for u, _ in parts])
        self.y = np.concatenate([y for _, y in parts])
        self.bounds = np.cumsum([0] + [u.size for u, _ in parts])
        self.skip = skip
        self.pairs = list(zip(self.bounds[:-1], self.bounds[1:], strict=True))
        self.rows: slice | np.ndarray = (slice(skip, None) if len(parts) == 1 else
                                         np.concatenate([np.arange(lo + skip, hi) for lo, hi in self.pairs]))

    def differenced(self) -> _Runs:
        """The runs with y(k) − y(k − 1) for y, each run from rest (y(−1) = 0)."""
        runs = _Runs.__new__(_Runs)
        runs.__dict__.update(self.__dict__)
        runs.y = np.concatenate([np.diff(self.y[lo:hi], prepend=0.0) for lo, hi in self.pairs])
        return runs

    def lfilter(self, b: np.ndarray, a: np.ndarray, v: np.ndarray) -> np.ndarray:
        """B(q)/A(q) v along axis 0, every run from rest (scipy's ``lfilter``, bit for bit:
        :func:`.kernels.lfilter`)."""
        if len(self.pairs) == 1:
            return lfilter(b, a, v)
        out = np.empty(v.shape)
        for lo, hi in self.pairs:
            lfilter(b, a, v[lo:hi], out[lo:hi])
        return out

    def filter_hats(self, b: np.ndarray, a: np.ndarray, hats: Hats) -> np.ndarray:
        """B(q)/A(q) Φ along axis 0 (row-major), every run from rest, for the basis Φ ``hats``
        (:meth:`.kernels.Hats.filtered`: scipy's ``lfilter`` of Φ, bit for bit)."""
        out = np.empty((self.u.size, hats.count))
        for lo, hi in self.pairs:
            hats.filtered(b, a, out[lo:hi], slice(lo, hi))
        return out


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


def _simulate_basis(dims: _Dims, th: np.ndarray, runs: _Runs, count: int, memo: dict | None = None):
    """Φ of ``count`` knots at x's quantiles, filtered by G₂ (if any), and the knots; every run
    from rest. ValueError where x = G₁u is not finite or takes a single value (no map on it).
    ``memo``: the last G₁'s unfiltered Φ (its rows' segments and values, :class:`.kernels.Hats`)
    and knots, kept there (x depends on G₁'s parameters alone: the Jacobian's columns of G₂'s
    parameters share them; the same arrays, not a new computation of them)."""
    b1, a1, b2, a2 = dims.build(th)
    key = (th[:dims.n1 + dims.m1].tobytes(), count)
    if memo is not None and key in memo:
        hats, knots = memo[key]
    else:
        x = runs.lfilter(b1, a1, runs.u)
        if not np.all(np.isfinite(x)):
            raise ValueError("the linear block's output is not finite")
        # the quantiles of the sorted copy: the same order statistics and interpolation, so the same
        # knots bit for bit, where numpy's selection of 2 × count order statistics costs ~3× the sort
        knots = np.unique(np.quantile(np.sort(x), np.linspace(0.002, 0.998, count)))
        if knots.size < 2:
            knots = np.unique([x.min(), x.max()])
            if knots.size < 2:
                raise ValueError("the linear block's output is constant: no static map can be fitted on it")
        hats = Hats(x, knots)
        if memo is not None:
            memo.clear()
            memo[key] = (hats, knots)
    return (hats.basis() if b2 is None else runs.filter_hats(b2, a2, hats)), knots


def _uncensored(y: np.ndarray, limits: Limits) -> np.ndarray:
    """Samples not measured at a limit (module docstring, 4)."""
    lo, hi = limits
    tol = 1e-9 * max(float(np.ptp(y)), 1e-300)
    return (y > lo + tol) & (y < hi - tol)


def _fit_values(phi: np.ndarray, y: np.ndarray, rows: slice | np.ndarray,
                limits: Limits = NO_LIMITS) -> np.ndarray:
    """f's values c minimising ‖Φc − y‖ over the uncensored samples of ``rows`` (the scored
    samples of :class:`_Runs`). By the
    normal equations (Cholesky of the column-scaled ΦᵀΦ, a few knots' columns, well conditioned
    as hat functions are): the refinements solve this thousands of times on tens of thousands of
    rows, where LAPACK's SVD-based least squares costs ~10× more (and ~100× on a loaded 2-core
    machine, its threads contending). Falls back to that least squares when ΦᵀΦ is not
    positive definite to working precision (a knot no sample reaches)."""
    if limits == NO_LIMITS:
        a, b = phi[rows], y[rows]                        # views for one run: no sample is censored
    else:
        keep = _uncensored(y, limits)[rows]
        a, b = phi[rows][keep], y[rows][keep]
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


def _residual(phi: np.ndarray, runs: _Runs, limits: Limits) -> np.ndarray:
    """The scored simulation error of the model whose basis is Φ, f's values fitted (variable
    projection), clipped at ``limits`` (module docstring, 4)."""
    fitted = phi @ _fit_values(phi, runs.y, runs.rows, limits)
    if limits != NO_LIMITS:         # a clip at ±inf is a copy of the same numbers: not made
        fitted = np.clip(fitted, *limits)
    return (fitted - runs.y)[runs.rows]


def _penalty(runs: _Runs) -> np.ndarray:
    """The residual a refinement sees where a trial θ gives no finite model: far above any fit's."""
    y = runs.y[runs.rows]
    return np.full(y.size, 1e3 * (1.0 + float(np.max(np.abs(y)))))


def fit_bla(runs: _Runs, n: int, max_nfev: int = 300, offset: bool = False
            ) -> tuple[np.ndarray, np.ndarray, float]:
    """Output-error linear model of order n (numerator n + 1 taps) over the runs, each from rest,
    y ≈ B(q)/A(q) u + d: (b, a, d), d = 0 unless ``offset`` (a constant the differenced output of
    an integrating system carries: a force offset or friction, which run integrated is a drift).
    Started from ARX least squares (each run's own regressors), its poles pulled inside
    |z| ≤ 0.995; ValueError where the data give no finite start."""
    u, y = runs.u, runs.y
    rows = np.concatenate([np.arange(lo + n, hi) for lo, hi in runs.pairs])
    if rows.size < 2 * n + 1 + offset:
        raise ValueError(f"order {n}: {rows.size} samples for {2 * n + 1 + offset} coefficients")
    X = np.column_stack([-y[rows - k] for k in range(1, n + 1)] + [u[rows - k] for k in range(n + 1)]
                        + ([np.ones(rows.size)] if offset else []))
    th, *_ = np.linalg.lstsq(X, y[rows], rcond=None)
    if not np.all(np.isfinite(th)):
        raise ValueError(f"order {n}: the least-squares start is not finite")
    a0 = np.concatenate([[1.0], th[:n]])
    a0 = np.poly(np.clip(np.abs(np.roots(a0)), 0, 0.995) * np.exp(1j * np.angle(np.roots(a0)))).real
    b0 = th[n:2 * n + 1]
    bad = _penalty(runs)
    p0 = np.concatenate([theta_from_poles(np.roots(a0)), b0])
    if offset:      # the ARX intercept is d·A(1); the output-error offset is d
        p0 = np.append(p0, th[-1] / np.sum(a0) if abs(np.sum(a0)) > 1e-6 else 0.0)

    def res(p: np.ndarray) -> np.ndarray:
        a = np.concatenate([[1.0], denominator_from_theta(p[:n], n)])
        r = (runs.lfilter(p[n:2 * n + 1], a, u) + (p[-1] if offset else 0.0) - y)[runs.rows]
        return r if np.all(np.isfinite(r)) else bad

    sol = least_squares(res, p0, bad.size, x_scale="jac", max_nfev=max_nfev)
    return (sol.x[n:2 * n + 1], np.concatenate([[1.0], denominator_from_theta(sol.x[:n], n)]),
            float(sol.x[-1]) if offset else 0.0)


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


def _refine(dims: _Dims, th0: np.ndarray, runs: _Runs, max_nfev: int, knots: int,
            limits: Limits = NO_LIMITS) -> np.ndarray:
    bad = _penalty(runs)
    memo: dict | None = {} if dims.n2 + dims.m2 else None      # G₂'s columns of the Jacobian share G₁'s basis

    def res(th: np.ndarray) -> np.ndarray:
        try:
            phi, _ = _simulate_basis(dims, th, runs, knots, memo)
        except ValueError:
            return bad
        r = _residual(phi, runs, limits)
        return r if np.all(np.isfinite(r)) else bad

    return least_squares(res, th0, bad.size, x_scale="jac", max_nfev=max_nfev, ftol=1e-10, xtol=1e-10).x


def _model(dims: _Dims, th: np.ndarray, runs: _Runs, fs: float, count: int,
           limits: Limits = NO_LIMITS, integrating: bool = False) -> SisoModel | SaturatedModel:
    """The model of θ, f refitted on ``runs``; ``integrating``: fitted on the differenced output,
    G₂ (or G₂ = 1) followed by the integrator 1/(1 − q⁻¹)."""
    phi, knots = _simulate_basis(dims, th, runs, count)
    c = _fit_values(phi, runs.y, runs.rows, limits)
    if not np.all(np.isfinite(c)):
        raise ValueError("the static map's values are not finite")
    b1, a1, b2, a2 = dims.build(th)
    if integrating:
        b2, a2 = (INTEGRATOR[0], INTEGRATOR[1]) if b2 is None else (b2, np.convolve(a2, INTEGRATOR[1]))
    g2 = None if b2 is None else HighPassFilter.from_ba(b2, a2)
    return _limited(SisoModel(HighPassFilter.from_ba(b1, a1), OutputNonlinearity(knots, c), g2, fs), limits)


MIN_FIT = 40
"""The fewest estimation samples of a record past its unscored start."""
MIN_HELD = 10
"""The fewest held-out samples of a record."""
PER_COEFFICIENT = 4
"""Estimation samples asked for per coefficient: an order n (2n + 1 coefficients of the linear
model) or a count of knots (f's values) beyond the estimation samples / 4 is not tried on a
short record. A rule of thumb fixed before any record was looked at, not tuned: it binds only
below ~800 estimation samples (the default 96 knots), so no benchmark's result depends on it."""
FAILS = (ValueError, ArithmeticError)
"""What a fit that fails numerically raises (LinAlgError is a ValueError): that fit is skipped."""


def _too_few(samples: int, left_out: list[str]) -> str:
    """The note on what a short record cannot support (:data:`PER_COEFFICIENT`)."""
    return (f"{samples} estimation samples: {' and '.join(left_out)} cannot be estimated from so few "
            f"(at least {PER_COEFFICIENT} samples per coefficient); not tried")


def _as_records(rec: SisoRecord | Sequence[SisoRecord]) -> list[SisoRecord]:
    """The records, each record of several runs (:func:`rtlift.core.records.join_runs`: a
    diagnosis's ``--train A --train B``) as its runs."""
    recs = [part for r in ([rec] if isinstance(rec, SisoRecord) else list(rec)) for part in split_runs(r)]
    if not recs:
        raise ValueError("no record given")
    fs = recs[0].fs_hz
    for r in recs[1:]:
        if abs(r.fs_hz - fs) > 1e-6 * fs:
            raise ValueError(f"{r.name} is sampled at {r.fs_hz:g} Hz, {recs[0].name} at {fs:g} Hz")
    return recs


@one_blas_thread
def identify_siso(rec: SisoRecord | Sequence[SisoRecord], structure: str = "wiener", order: int | None = None,
                  options: SisoOptions | None = None, limits: Limits = NO_LIMITS,
                  where: str = "output") -> SisoModel:
    """The model of ``structure`` for one record or several (module docstring; several: each its
    own run from rest, one cost, each's last ``holdout`` fraction held out), its output (or, for
    nonlinear feedback, its state) clipped at ``limits`` if given (4); ValueError (one line) on
    data it cannot be identified from. An order, a split or a knot count whose fit fails
    numerically is skipped and named in ``provenance["skipped"]``; what a short record cannot
    support is not tried and said in ``provenance["notes"]``."""
    opt = options or SisoOptions()
    if structure not in STRUCTURES:
        raise ValueError(f"unknown structure {structure!r}; expected one of {', '.join(STRUCTURES)}")
    if not (structure in LIMITED.get(where, ()) or where == "output" and limits == NO_LIMITS):
        raise ValueError(f"a limit where {where!r} is built for the output of {listed(LIMITED['output'])} and "
                         f"for the state of {listed(LIMITED['state'])}")
    recs = _as_records(rec)
    fs = recs[0].fs_hz
    n_ests = [int(round((1.0 - opt.holdout) * r.u.size)) for r in recs]
    skip = min(opt.skip, min(n_ests) // 10)
    for r, n_est in zip(recs, n_ests, strict=True):
        if n_est - skip < MIN_FIT or r.u.size - n_est < MIN_HELD:
            raise ValueError(f"record too short ({r.u.size} samples in {r.name}): at least {MIN_FIT} to fit "
                             f"and {MIN_HELD} held out ({100 * opt.holdout:.0f} %) are needed")
    name = ", ".join(r.name for r in recs)
    if structure in ("store_chain", "nonlinear_feedback"):
        if len(recs) > 1:
            raise ValueError(f"{structure} is identified from one record ({len(recs)} given: "
                             f"{', '.join(r.name for r in recs)}); give one")
        (r,), (n_est,) = recs, n_ests
        notes = []
        if structure == "nonlinear_feedback":      # a(n), b(n), b₀, k₂, k₃ and the offset: 2n + 4 coefficients
            budget = (n_est - skip) // PER_COEFFICIENT
            fitted = tuple(n for n in opt.feedback_orders if 2 * n + 4 <= budget)
            dropped = [str(n) for n in opt.feedback_orders if n not in fitted]
            if dropped:
                notes.append(_too_few(n_est - skip, [f"order{'s' if len(dropped) > 1 else ''} {', '.join(dropped)}"]))
                opt = replace(opt, feedback_orders=fitted or (min(opt.feedback_orders),))
        ue, ye = r.u[:n_est], r.y[:n_est]
        cost = slice(0, min(n_est, opt.cost_samples))
        fit = identify_store_chain if structure == "store_chain" else identify_feedback
        args = (ue[cost], ye[cost], r.u, r.y, n_est, skip, fs, opt, limits) + (
            (where, _integrating_start(r, n_est, skip, opt, fs) if limits == NO_LIMITS else None)
            if structure == "nonlinear_feedback" else ())
        model = fit(*args)
        model.provenance.update(tool="rtlift identify --record", record=name, holdout_fraction=opt.holdout)
        if notes:
            model.provenance["notes"] = notes
        model.metrics["train_rmse"] = _rmse(model, ue, ye, skip)
        return model
    # non-finite trials are caught and skipped, and a trial's ill-conditioned numerator is judged by its
    # held-out error: neither is warned about
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", signal.BadCoefficients)
        return _identify_w(recs, n_ests, skip, structure, order, opt, limits)


def _linear(runs: _Runs, n: int, integrating: bool, held_parts: list, fs: float
            ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The output-error linear model of order n on ``runs`` (on their differenced output, with a
    constant d, where ``integrating``: run integrated) and its held-out RMSE: (b, a, d, RMSE);
    FAILS where it cannot be fitted or its held-out error is not finite."""
    b, a, d = fit_bla(runs, n, offset=integrating)
    lin = SisoModel(HighPassFilter.from_ba(b, a), OutputNonlinearity([0.0, 1.0], [d, 1.0 + d]),
                    HighPassFilter.from_ba(*INTEGRATOR) if integrating else None, fs)
    held = _pooled_rmse(lin, held_parts)
    if not np.isfinite(held):
        raise ValueError("its held-out error is not finite")
    return b, a, d, held


def _integrating_start(r: SisoRecord, n_est: int, skip: int, opt: SisoOptions, fs: float) -> tuple | None:
    """The rule of the integrating variant (module docstring, 5) for ``nonlinear_feedback``: the
    first-order linear model (b, a, d) fitted on the differenced output (the start
    :func:`rtlift.sysid.feedback.identify_feedback` refines), where run integrated it holds out
    better than the first-order one fitted on the output, or where that one's pole has a time
    constant 1/(1 − p) of at least the estimation samples (an integrator, as far as these data
    tell: both linear models drift where friction is outside them, and which drifts less over
    the held-out part is chance — on the simulated positioning case, calibration seed 1, the
    plain one held out 17 mm against 29 mm, its pole 1 − 10⁻⁷); else None. First order: the rule
    costs two short fits (the plain variant's search is the diagnosis's own)."""
    n = min(n_est, opt.cost_samples)
    runs = _Runs([(r.u[:n], r.y[:n])], skip)
    held = [(r.u, r.y, n_est)]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", signal.BadCoefficients)
        try:
            b, a, d, integrated = _linear(runs.differenced(), 1, True, held, fs)
        except FAILS:
            return None
        try:
            _, a_plain, _, plain = _linear(runs, 1, False, held, fs)
            pole = float(-a_plain[1])
        except FAILS:
            plain, pole = np.inf, 0.0
    return (b, a, d) if integrated < plain or pole >= 1.0 - 1.0 / (n_est - skip) else None


def _identify_w(recs: list[SisoRecord], n_ests: list[int], skip: int, structure: str, order: int | None,
                opt: SisoOptions, limits: Limits) -> SisoModel | SaturatedModel:
    """:func:`identify_siso` for the W-block structures (module docstring, 1–4)."""
    fs = recs[0].fs_hz
    est = _Runs([(r.u[:n], r.y[:n]) for r, n in zip(recs, n_ests, strict=True)], skip)
    share = max(opt.cost_samples // len(recs), 1)
    cost = _Runs([(r.u[:min(n, share)], r.y[:min(n, share)]) for r, n in zip(recs, n_ests, strict=True)], skip)
    held_parts = [(r.u, r.y, n) for r, n in zip(recs, n_ests, strict=True)]
    fit_parts = [(r.u[:n], r.y[:n], skip) for r, n in zip(recs, n_ests, strict=True)]
    budget = (est.u.size - skip * len(recs)) // PER_COEFFICIENT
    notes, skipped = [], {}
    orders = (order,) if order else tuple(n for n in opt.orders if 2 * n + 1 <= budget)
    knots = min(opt.knots, budget)
    more = tuple(k for k in opt.more_knots if k <= budget)
    dropped = [] if order else [str(n) for n in opt.orders if n not in orders]
    left_out = [f"order{'s' if len(dropped) > 1 else ''} {', '.join(dropped)}"] if dropped else []
    if knots < opt.knots or len(more) < len(opt.more_knots):
        left_out.append(f"f on more than {max(knots, 2)} knots")
    orders = orders or (1,)
    if left_out:
        notes.append(_too_few(est.u.size - skip * len(recs), left_out))
    knots = max(knots, 2)
    # the integrating variant (module docstring, 5): fitted on the differenced output, run integrated
    variants = (False, True) if limits == NO_LIMITS else (False,)
    runs = {False: (cost, est), True: (cost.differenced(), est.differenced())}
    bla = {}

    def linear(n: int, integrating: bool) -> None:
        """The linear model of order n (on Δy where ``integrating``) into ``bla``, or its failure into ``skipped``."""
        try:
            b, a, _, held = _linear(runs[integrating][0], n, integrating, held_parts, fs)
            bla[n, integrating] = (b, a, held)
        except FAILS as exc:
            skipped[f"order {n}{' integrating' if integrating else ''}"] = str(exc)

    for n, integrating in itertools.product(orders, variants):
        linear(n, integrating)
    if not bla:
        raise ValueError("no linear model could be fitted (" + "; ".join(f"{k}: {v}" for k, v in skipped.items())
                         + ")")
    # the plain model always; the integrating one too where its linear model is the better held out
    best_bla = min(bla, key=lambda k: bla[k][2])
    tried = [k for k in ((min((k for k in bla if not k[1]), key=lambda k: bla[k][2], default=None)), best_bla)
             if k is not None]
    # a linear model that holds out no better than the estimation data's mean says nothing of G₁ (an
    # even map: the BLA of |x| is 0): then the Wiener fit also starts from random poles (module docstring, 6)
    level = float(np.mean(est.y[est.rows]))
    mean_rmse = float(np.sqrt(np.mean(np.concatenate([y[k:] - level for _, y, k in held_parts]) ** 2)))
    blind = bla[best_bla][2] >= mean_rmse
    if best_bla[1] and not blind and bla[tried[0]][2] >= mean_rmse:
        tried = [best_bla]      # the plain linear model holds out no better than the mean, the integrating one does
    if blind and structure == "wiener" and not order:
        # the linear model's order says nothing either: every order of BLIND_ORDERS is started blind, and the
        # held-out error chooses among them (module docstring, 6)
        blind_orders = [n for n in BLIND_ORDERS if n <= max(opt.orders) and 2 * n + 1 <= budget]
        for n in blind_orders:
            if (n, False) not in bla:
                linear(n, False)
        tried = [(n, False) for n in blind_orders if (n, False) in bla] or tried
    best = None
    for n, integrating in dict.fromkeys(tried):
        b, a, bla_holdout = bla[n, integrating]
        found = _w_stage(structure, b, a, *runs[integrating], held_parts, fs, knots, more, opt, limits, integrating,
                         skipped, MULTI_STARTS if blind and structure == "wiener" else 0)
        if found is not None and (best is None or found[0] < best[0]):
            best = (*found, n, bla_holdout, integrating)
    if best is None:
        raise ValueError(f"no {structure} model could be fitted (" + "; ".join(f"{k}: {v}" for k, v in skipped.items())
                         + ")")
    held, model, knots, starts, n, bla_holdout, integrating = best
    model.provenance = {"tool": "rtlift identify --record", "record": ", ".join(r.name for r in recs),
                        "structure": structure, "bla_order": n, "bla_holdout_rmse": bla_holdout,
                        "holdout_fraction": opt.holdout, "splits_refined": starts, "knots": knots}
    if integrating:
        model.provenance["integrating"] = ("fitted on the differenced output, run integrated: its held-out error "
                                           "was the lower")
    if blind and structure == "wiener":
        model.provenance["random_starts"] = (f"{MULTI_STARTS} random pole sets besides the linear model's (it held "
                                             "out no better than the mean)")
    if len(recs) > 1:
        model.provenance["records"] = [r.name for r in recs]
    if skipped:
        model.provenance["skipped"] = skipped
    if notes:
        model.provenance["notes"] = notes
    model.metrics = {"holdout_rmse": held, "train_rmse": _pooled_rmse(model, fit_parts)}
    return model


def _w_stage(structure: str, b: np.ndarray, a: np.ndarray, cost: _Runs, est: _Runs, held_parts: list, fs: float,
             knots: int, more: tuple[int, ...], opt: SisoOptions, limits: Limits, integrating: bool,
             skipped: dict[str, str], random_starts: int = 0
             ) -> tuple[float, SisoModel | SaturatedModel, int, int] | None:
    """The W-block model from the linear model B/A (module docstring, 2–3; with ``random_starts``,
    6): (held-out RMSE, model, knots, starts refined), or None where every start failed (each
    failure named in ``skipped``)."""
    n = a.size - 1
    tag = " integrating" if integrating else ""
    if structure == "wiener":
        dims = _Dims(n, b.size - 1, 0, 0)
        starts = [(dims, (b, a, None, None)), *_random_starts(dims, cost, knots, opt, limits, random_starts)]
    else:
        starts = []
        for b1, a1, b2, a2 in _splits(b, a):
            dims = _Dims(a1.size - 1, b1.size - 1, a2.size - 1, b2.size - 1)
            if b1[0] == 0 or b2[0] == 0:
                continue
            th = _Dims.theta(b1, a1, b2, a2)
            try:
                phi, _ = _simulate_basis(dims, th, cost, knots)
            except FAILS:
                continue
            r = _residual(phi, cost, limits)
            if np.all(np.isfinite(r)):
                starts.append((float(np.sum(r**2)), dims, (b1, a1, b2, a2)))
        starts = [(d, bb) for _, d, bb in sorted(starts, key=lambda s: s[0])[:opt.keep]]
    best = None
    for i, (dims, (b1, a1, b2, a2)) in enumerate(starts):
        try:
            th = _refine(dims, _Dims.theta(b1, a1, b2, a2), cost, opt.max_nfev, knots, limits)
            model = _model(dims, th, est, fs, knots, limits, integrating)
            held = _pooled_rmse(model, held_parts)
        except FAILS as exc:
            skipped[f"order {n}{tag} start {i + 1}"] = str(exc)
            continue
        if np.isfinite(held) and (best is None or held < best[0]):
            best = (held, model, dims, th, knots)
    if best is None:
        return None
    for count in more:      # the best one's f on finer knots, refined jointly again from there
        held0, _, dims, th0, _ = best
        try:
            th = _refine(dims, th0, cost, opt.more_knots_nfev, count, limits)
            model = _model(dims, th, est, fs, count, limits, integrating)
            held = _pooled_rmse(model, held_parts)
        except FAILS as exc:
            skipped[f"order {n}{tag} {count} knots"] = str(exc)
            continue
        if held < held0:
            best = (held, model, dims, th, count)
    return best[0], best[1], best[4], len(starts)


MULTI_STARTS = 8
"""Random pole sets a blind Wiener fit starts from (module docstring, 6)."""
BLIND_ORDERS = (1, 2, 3, 4)
"""The orders a blind Wiener fit is started at (those up to the largest of ``orders``), each
from :data:`MULTI_STARTS` random pole sets (module docstring, 6). Not beyond 4: a random start in
more dimensions rarely reaches the optimum (on the simulated coupled-drives case, calibration
seed 1, order 4 from 8 starts held out 0.32, order 3 0.045, at a noise level of 0.03; order 6
took 46 s)."""


def _random_starts(dims: _Dims, cost: _Runs, knots: int, opt: SisoOptions, limits: Limits, count: int) -> list:
    """``count`` random stable G₁ of ``dims`` (pole pairs of radius 0.5–0.98 and angle 0.05–π/2, a
    real pole for an odd order, zeros at the origin; seeded: the same data give the same model),
    each refined for a tenth of ``max_nfev``; the ``keep`` best by cost, as (dims, (b, a, None, None))."""
    rng = np.random.default_rng(0)
    quick = []
    for _ in range(count):
        k = dims.n1 // 2
        r, w = rng.uniform(0.5, 0.98, k), rng.uniform(0.05, np.pi / 2, k)
        poles = np.concatenate([r * np.exp(1j * w), r * np.exp(-1j * w), rng.uniform(0.5, 0.98, dims.n1 % 2)])
        a0 = np.real(np.poly(poles))
        b0 = np.zeros(dims.m1 + 1)
        b0[0] = 1.0
        try:
            th = _refine(dims, _Dims.theta(b0, a0, None, None), cost, max(opt.max_nfev // 10, 3), knots, limits)
            phi, _ = _simulate_basis(dims, th, cost, knots)
        except FAILS:
            continue
        res = _residual(phi, cost, limits)
        if np.all(np.isfinite(res)):
            b1, a1, _, _ = dims.build(th)
            quick.append((float(np.sum(res**2)), (b1, a1, None, None)))
    return [(dims, start) for _, start in sorted(quick, key=lambda q: q[0])[:opt.keep]]

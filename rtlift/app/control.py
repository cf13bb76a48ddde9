"""Lift tracking around the observer: ΔCL reference in, burst envelope Cμ out (400 Hz).

The plant seen from the envelope is the hybrid model's slow part, a Wiener system
(ARCHITECTURE.md): ``x(k) = A x(k−1) + B Cμ(k)``, ``ΔCL_L = N(Cμ) · C x`` (or ``f(C x)``);
the burst ripple (the high-passed convolution) has no mean. Its static map is therefore

    S(Cμ) = nl(Cμ, G₀ Cμ),    G₀ = C (I − A)⁻¹ B   (the LTI DC gain),

concave and saturating. :class:`LiftController` implements

    v = r + K_p ē_f + K_x (ΔĈL_mean − ΔĈL_last) + I,        u = S⁻¹(v) clamped to [0, Cμ_reach]

with ``ē`` the tracking error ``r − ΔĈL`` averaged over one burst period (the ripple's
period, so the average removes it), ``ē_f`` it through the lead–lag ``g (Z − a)/(Z − b)``
at the burst rate (none when a = b = 0), ``r`` the reference and ``I`` the integral of
``(T / T_i) ē_f``. The ``K_x`` term acts on the latest estimate's departure from the period's
mean: half a period fresher than the mean, it buys phase; the burst ripple's part of it is a
constant at the fixed burst phase of the decisions, which the integral (on the mean only)
absorbs, so the mean still tracks ``r`` exactly. In the ``pi2`` structure a second lead–lag
``g₂ (Z − c)/(Z − d)``, g₂ = (1 − d)/(1 − c), filters the whole feedback: both its inputs, ``ē``
before the first lead–lag and ``ΔĈL_mean − ΔĈL_last`` before ``K_x`` (none when c = d = 0).
``rtlift control`` takes (K_p, T_i, a, b) from the design made with
python-control on the identified model (:mod:`rtlift.app.control_design`), scheduled over
Cμ; the hand-set PI below (K_p 0.5, T_i 0.25 s, no lead) is what ``--kp``/``--ti`` replace.
With the feedback off, ``u = S⁻¹(r)``: pure feedforward through the
inverse of the identified static map and DC gain. Working in ΔCL units before the inverse
makes the loop gain independent of the operating point (the map's slope varies about 5× over
its range), so one pair (K_p, T_i) serves the whole range.

Why PI with conditional integration. The envelope can only change at burst onsets (8 Hz),
so a model-predictive law has one move per 125 ms and little to gain over PI on a plant whose
slow part is nearly first order; what it needs is bounded behaviour at the actuator limits
(Cμ ≥ 0, the firmware's 200 V: Cμ_reach, :data:`ACTUATOR_CMU_LIMIT`, beyond the identified map's
top Cμ_max = 0.022, the map extrapolated there — under an actuator fade the delivered Cμ stays inside
it). Conditional integration (the integrator holds while the
command is saturated and the error would push it further) needs no extra tuning constant,
unlike back-calculation's tracking time, and guarantees the integrator never grows while the
actuator is pinned, so a reference beyond reach leaves no windup to unwind. The integrator is
also clamped to the map's range.

Measured on the model as plant (tests/test_control.py; steps 0 → 0.10 → 0.16 → 0.06 with an
actuator fade to 75 %): tracking RMSE 0.0091 with feedback against 0.0191 feedforward only
(ratio 0.48), step settling ≈ 1.1 s, recovery ≈ 0.8 s after 4 s at an unreachable reference.
A two-degree-of-freedom variant (feedback on the model's expected response to the
feedforward instead of the reference) settled in 0.45 s but only reached a ratio of 0.66: the
error on the ``r`` side also buys back part of the plant's own lag, so plain PI is the default.

The internal-model controller (``ControlConfig.youla``; :class:`~rtlift.app.control_design.YoulaGains`).
Instead of the PI, at each decision k (ΔCL units, e = r − ΔĈL: e_A on the period's mean, e_X on
the latest estimate)

    ê_A[k] = e_A[k] + Σ_{j≥1} P̂_A[j] w[k−j],   ê_X[k] = e_X[k] + Σ_{j≥1} P̂_X[j] w[k−j]
    w[k] = Σ_i Q_A[i] ê_A[k−i] + Q_X[i] ê_X[k−i],      v = r + w

i.e. K = Q/(1 − Q_A P̂_A − Q_X P̂_X) on (e_A, e_X): the model's response to the controller's own
past outputs is added back to the error (what is left is the disturbance), and the Youla
parameter Q, designed by a linear programme on the lifted plant P̂, acts on it. Every state is a
finite history (P̂ and Q are FIR at the burst rate); the taps are interpolated in Cμ between the
schedule's rows (held beyond them), as the PI's gains; w is stored as applied after the map's
limits, so a reference beyond reach winds nothing up (the model sees the output it really had).

:meth:`LiftController.step` allocates nothing and does no I/O: call it once per sample; it
decides a new envelope every ``period`` samples (``updated`` is true then: send it).
"""

from __future__ import annotations

import json
import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtlift.core.errors import UserError
from rtlift.core.programs import ENVELOPE_LIMIT_V
from rtlift.core.rate import FS_HZ
from rtlift.core.wing import CMU_PER_VOLT2

BURST_PERIOD_SAMPLES = 50
"""The lift-optimal 8 Hz burst rate at 400 Hz: the envelope changes once per period."""
DEFAULT_CMU_MAX = 0.022
"""Top of the identified static map (the bench's 200 V limit gives ≈ 0.0244)."""
ACTUATOR_CMU_LIMIT = CMU_PER_VOLT2 * ENVELOPE_LIMIT_V ** 2
"""The actuator's own top, Cμ = κ V² at the firmware's 200 V clamp with the rig's κ (≈ 0.0244): how
far the feedback may drive the envelope (``ControlConfig.cmu_reach``). Under a 70 % actuator fade the
reference 0.16 needs Cμ 0.0275 on calibration draw 2 (0.019 without it): held at the map's top 0.022
the loop's tracking error there was 0.0194 against 0.0102 with this reach (docs/results/control.md,
"Fifth pass")."""
MAP_POINTS = 201


@dataclass(frozen=True)
class ControlConfig:
    """Controller settings: ``kp`` (ΔCL per ΔCL), ``ti_s`` integral time (s), ``lead_zero`` a
    and ``lead_pole`` b of the lead–lag g (Z − a)/(Z − b) on the averaged error (0, 0: none),
    ``kx`` the gain on the latest estimate's departure from the period's mean (0: none),
    ``schedule`` rows ``(Cμ, kp, ti_s, a, b, kx)`` in increasing Cμ that replace the five by
    their interpolation at the feedforward's Cμ (:mod:`rtlift.app.control_design` designs them),
    or ``(Cμ, kp, ti_s, a, b, kx, c, d)`` with a second lead–lag g₂ (Z − c)/(Z − d) on the whole
    feedback (the ``pi2`` structure; a 6-column row has c = d = 0, no second lead–lag),
    ``feedback``, ``cmu_max`` the top of the identified static map (Cμ: the feedforward's and the
    design's range), ``cmu_reach`` how far the feedback may drive the envelope (Cμ, the actuator's
    own limit :data:`ACTUATOR_CMU_LIMIT`; beyond ``cmu_max`` through the model's map extrapolated),
    ``period`` samples between envelope updates."""

    kp: float = 0.5
    ti_s: float = 0.25
    feedback: bool = True
    cmu_max: float = DEFAULT_CMU_MAX
    period: int = BURST_PERIOD_SAMPLES
    fs_hz: float = FS_HZ
    lead_zero: float = 0.0
    lead_pole: float = 0.0
    kx: float = 0.0
    cmu_reach: float = ACTUATOR_CMU_LIMIT
    schedule: tuple[tuple[float, float, float, float, float, float], ...] = ()
    youla: tuple[tuple[Any, ...], ...] = ()
    """Rows ``(Cμ, Q_A taps, Q_X taps, P_A taps, P_X taps)`` in increasing Cμ: the internal-model
    (Youla) controller instead of the PI (:class:`LiftController`, "The internal-model controller";
    :mod:`rtlift.app.control_design` designs them). Empty: the PI."""

    def __post_init__(self) -> None:
        for name in ("kp", "ti_s", "cmu_max", "cmu_reach", "fs_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0) and not (name == "kp" and v == 0):
                raise ValueError(f"control {name} must be a positive number, got {v!r}")
        if not isinstance(self.period, int) or self.period < 1:
            raise ValueError(f"control period must be a positive integer, got {self.period!r}")
        rows = [(0.0, self.kp, self.ti_s, self.lead_zero, self.lead_pole, self.kx), *self.schedule]
        for row in rows:
            if len(row) not in (6, 8):
                raise ValueError(f"control schedule rows are (cmu, kp, ti_s, a, b, kx[, c, d]); got {row!r}")
            cmu, kp, ti, a, b, kx, c, d = (*row, 0.0, 0.0)[:8]
            if not (kp >= 0 and ti > 0 and max(abs(a), abs(b), abs(c), abs(d)) < 1
                    and math.isfinite(kp + ti + cmu + kx)):
                raise ValueError(f"control gains must have kp >= 0, ti_s > 0, |a|, |b|, |c|, |d| < 1; got "
                                 f"{row[1:]!r}")
        if len({len(row) for row in self.schedule}) > 1:
            raise ValueError("control schedule: every row must have the same number of columns")
        if any(r1[0] >= r2[0] for r1, r2 in zip(self.schedule, self.schedule[1:], strict=False)):
            raise ValueError("control schedule: Cμ must increase from row to row")
        shapes = {tuple(len(t) for t in row[1:]) for row in self.youla if len(row) == 5}
        if self.youla and (len(shapes) != 1 or any(len(r) != 5 for r in self.youla)):
            raise ValueError("control youla rows are (cmu, qa, qx, pa, px) with the same tap counts in every row")
        for row in self.youla:
            nq, nx, npa, npx = (len(t) for t in row[1:])
            if nq != nx or npa != npx or nq < 1 or npa < 1 or not all(
                    math.isfinite(float(v)) for t in row[1:] for v in t) or not math.isfinite(float(row[0])):
                raise ValueError(f"control youla row at Cμ {row[0]!r}: Q_A, Q_X and P_A, P_X must be finite and "
                                 "of equal lengths")
        if any(r1[0] >= r2[0] for r1, r2 in zip(self.youla, self.youla[1:], strict=False)):
            raise ValueError("control youla rows: Cμ must increase from row to row")


def gains_text(cfg: ControlConfig) -> str:
    """The feedback gains of ``cfg`` as one line of JSON (a command log's ``gains`` metadata:
    ``rtlift replay`` rebuilds the same controller from it, floats exact)."""
    return json.dumps({"kp": cfg.kp, "ti_s": cfg.ti_s, "lead_zero": cfg.lead_zero, "lead_pole": cfg.lead_pole,
                       "kx": cfg.kx, "cmu_reach": cfg.cmu_reach, "schedule": [list(row) for row in cfg.schedule],
                       "youla": [[row[0], *(list(t) for t in row[1:])] for row in cfg.youla]})


def config_from_gains_text(text: str, feedback: bool, fs_hz: float) -> ControlConfig:
    """The :class:`ControlConfig` :func:`gains_text` wrote (:class:`UserError` if garbled); a log
    written before ``cmu_reach`` was its feedback held at the map's top, ``cmu_max``."""
    try:
        d = json.loads(text)
        return ControlConfig(kp=float(d["kp"]), ti_s=float(d["ti_s"]), lead_zero=float(d["lead_zero"]),
                             lead_pole=float(d["lead_pole"]), kx=float(d["kx"]),
                             cmu_reach=float(d.get("cmu_reach", DEFAULT_CMU_MAX)),
                             schedule=tuple(tuple(float(v) for v in row) for row in d["schedule"]),
                             youla=youla_rows(d.get("youla", ())), feedback=feedback, fs_hz=fs_hz)
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f"control gains {text[:60]!r}: not valid ({exc})") from None


def lead_lag(y_last: float, x: float, x_last: float, a: float, b: float, g: float) -> float:
    """One step of the lead–lag g (Z − a)/(Z − b) at the burst rate: y(k) = b y(k−1) + g (x(k) − a x(k−1)),
    g = (1 − b)/(1 − a) (unit gain at DC; x itself when a = b = 0)."""
    return b * y_last + g * (x - a * x_last)


def youla_rows(rows: Any) -> tuple[tuple[Any, ...], ...]:
    """``(Cμ, Q_A, Q_X, P_A, P_X)`` rows as tuples of floats (from JSON lists)."""
    return tuple((float(r[0]), *(tuple(float(v) for v in t) for t in r[1:])) for r in rows)


def youla_at(rows: Any, cmu: float, out: list[list[float]]) -> None:
    """The internal-model controller's taps at ``cmu`` into ``out`` (four lists: Q_A, Q_X, P_A,
    P_X), linear in Cμ between rows, held beyond them (as the PI schedule); no allocation."""
    j = 1
    while j < len(rows) - 1 and cmu >= rows[j][0]:
        j += 1
    lo, hi = rows[max(j - 1, 0)], rows[min(j, len(rows) - 1)]
    w = 0.0 if hi[0] <= lo[0] else min(max((cmu - lo[0]) / (hi[0] - lo[0]), 0.0), 1.0)
    for k in range(4):
        a, b, o = lo[k + 1], hi[k + 1], out[k]
        for i in range(len(o)):
            o[i] = a[i] + w * (b[i] - a[i])


def dc_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> float:
    """G₀ = C (I − A)⁻¹ B of x(k) = A x(k−1) + B u(k), y = C x (input at time k)."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    return float(np.asarray(C, dtype=float) @ np.linalg.solve(np.eye(len(A)) - A,
                                                              np.asarray(B, dtype=float)))


def static_map(model: Any, cmu_max: float, points: int = MAP_POINTS,
               reach: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(Cμ grid on [0, cmu_max], S(Cμ)) of the model's Wiener part (and of the interaction
    structure's burst part, whose slow response has a mean), made non-decreasing; with ``reach`` >
    ``cmu_max`` the grid goes on at the same spacing to ``reach`` (the model extrapolated). The Wiener
    input is the envelope, or what the interaction structure's ``delivered_envelope`` stage makes
    of it under lift-optimal bursting (:meth:`~rtlift.blocks.delivered.DeliveredEnvelope.steady`:
    the envelope, or its static lift)."""
    w = model.wiener
    g0 = dc_gain(w.A, w.B, w.C)
    cmu = np.linspace(0.0, cmu_max, points)
    if reach > cmu_max:
        more = max(1, math.ceil((reach - cmu_max) * (points - 1) / cmu_max))
        cmu = np.r_[cmu, np.linspace(cmu_max, reach, more + 1)[1:]]
    steady = getattr(model.input_stages[-1], "steady", None) if model.input_stages else None
    u = np.array([steady(c) for c in cmu]) if steady is not None else cmu
    nl = w.nonlinearity
    if hasattr(nl, "gain_at"):
        dcl = np.array([nl.gain_at(v) * g0 * v for v in u])
    else:
        dcl = np.array([nl.output_at(v, g0 * v) for v in u])
    burst = getattr(model.convolution, "steady_output", None)     # the interaction structure's slow burst part
    if burst is not None:
        dcl = dcl + np.array([burst(c, v) for c, v in zip(cmu, u, strict=True)])
    return cmu, np.maximum.accumulate(dcl)


class LiftController:
    """Feedforward through S⁻¹ plus PI feedback on the observer's ΔĈL (module docstring)."""

    def __init__(self, model: Any, config: ControlConfig | None = None) -> None:
        self.config = cfg = config or ControlConfig()
        cmu, dcl = static_map(model, cfg.cmu_max, reach=cfg.cmu_reach if cfg.feedback else 0.0)
        keep = np.concatenate([[True], np.diff(dcl) > 0])  # strictly increasing for the inverse
        self._map_dcl = [float(v) for v in dcl[keep]]
        self._map_cmu = [float(v) for v in cmu[keep]]
        if len(self._map_dcl) < 2 or not all(map(math.isfinite, self._map_dcl)):
            raise UserError("model: its static map does not increase with Cμ; cannot invert it for control")
        self.dcl_min = self._map_dcl[0]
        self.dcl_max = float(dcl[MAP_POINTS - 1])
        """S(cmu_max): the top of the identified map (the design's operating range)."""
        self.dcl_reach = self._map_dcl[-1]
        """S(cmu_reach): the top the feedback may drive ``v`` to (the actuator's limit; with the
        feedback off, S(cmu_max))."""
        self._rows = [(*(float(v) for v in row), 0.0, 0.0)[:8] for row in cfg.schedule]
        """The schedule's rows, each ``(Cμ, kp, ti_s, a, b, kx, c, d)`` (c = d = 0: no second lead–lag)."""
        self._set_gains(cfg.kp, cfg.ti_s, cfg.lead_zero, cfg.lead_pole, cfg.kx)
        self._youla = youla_rows(cfg.youla)
        self._taps = [[0.0] * len(t) for t in self._youla[0][1:]] if self._youla else []
        """Q_A, Q_X, P_A, P_X in force (:func:`youla_at`), filled in place at each decision."""
        self.reset()

    def _set_gains(self, kp: float, ti_s: float, a: float, b: float, kx: float, c: float = 0.0,
                   d: float = 0.0) -> None:
        cfg = self.config
        self.kp = kp
        self.kx = kx
        self._gain_i = cfg.period / (cfg.fs_hz * ti_s)
        self._a = a
        self._b = b
        self._g = (1.0 - b) / (1.0 - a)
        self._c = c
        self._d = d
        self._g2 = (1.0 - d) / (1.0 - c)

    def _schedule_at(self, cmu: float) -> None:
        """Gains of the schedule at ``cmu`` (linear between rows, held beyond them)."""
        rows = self._rows
        if cmu <= rows[0][0]:
            r0 = rows[0]
            self._set_gains(r0[1], r0[2], r0[3], r0[4], r0[5], r0[6], r0[7])
            return
        for j in range(1, len(rows)):
            hi = rows[j]
            if cmu < hi[0]:
                lo = rows[j - 1]
                w = (cmu - lo[0]) / (hi[0] - lo[0])
                self._set_gains(lo[1] + w * (hi[1] - lo[1]), lo[2] + w * (hi[2] - lo[2]),
                                lo[3] + w * (hi[3] - lo[3]), lo[4] + w * (hi[4] - lo[4]),
                                lo[5] + w * (hi[5] - lo[5]), lo[6] + w * (hi[6] - lo[6]),
                                lo[7] + w * (hi[7] - lo[7]))
                return
        last = rows[-1]
        self._set_gains(last[1], last[2], last[3], last[4], last[5], last[6], last[7])

    def reset(self) -> None:
        self.feedforward = 0.0
        """The last feedforward envelope S⁻¹(r) (Cμ)."""
        self.integral = 0.0
        self.envelope = 0.0
        """The last decided envelope (Cμ)."""
        self.saturated = False
        """Whether the last decision sat at an actuator limit."""
        self.updated = False
        self.feedback_dcl = 0.0
        """The last decision's feedback v − r (ΔCL, after the limits)."""
        self._filtered = 0.0
        """The lead–lags' output (ΔCL), what the PI acts on."""
        self._last_err = 0.0
        """The first lead–lag's last input (ΔCL)."""
        self._e2 = 0.0
        """The second lead–lag's output on the mean error (ΔCL; the mean error itself without one)."""
        self._last_e = 0.0
        self._x2 = 0.0
        """The second lead–lag's output on ΔĈL_mean − ΔĈL_last (ΔCL; that difference without one)."""
        self._last_x = 0.0
        self._point = 0.0
        self._start_period()
        nq, npl = (len(self._taps[0]), len(self._taps[2])) if getattr(self, "_taps", None) else (0, 0)
        self._w_hist = [0.0] * npl
        """The internal-model controller's past outputs w = v − r as applied (after the limits), a ring."""
        self._ea_hist = [0.0] * nq
        """Its past corrected errors ê_A = e_A + P_A w (the disturbance's estimate, negated), a ring."""
        self._ex_hist = [0.0] * nq
        self._w_pos = 0
        self._e_pos = 0

    def _start_period(self) -> None:
        """Empty the decision period's accumulators (sums of error, estimate and reference over
        the samples since the last decision, and their counts)."""
        self._count = 0
        self._err_sum = 0.0
        self._est_sum = 0.0
        self._ref_sum = 0.0
        self._ref_n = 0
        self._n = 0

    def carry_from(self, other: LiftController) -> None:
        """Take over ``other``'s integrator, last decision and place in the period (a model swap
        while the loop runs: the new static map serves the next decision)."""
        probe = object.__new__(LiftController)
        LiftController.reset(probe)            # the state is what reset() sets: one list of it
        for name in vars(probe):
            setattr(self, name, getattr(other, name))
        span = self.dcl_reach - self.dcl_min
        self.integral = min(max(self.integral, -span), span)

    def sync(self, samples_to_decision: int) -> None:
        """Make the next decision fall ``samples_to_decision`` samples from now (align the
        updates ahead of the device's burst onsets)."""
        self._count = self.config.period - max(1, int(samples_to_decision))

    def inverse(self, dcl: float) -> float:
        """S⁻¹(ΔCL) as Cμ, clamped to the map's range [0, cmu_reach] ([0, cmu_max] with the feedback off)."""
        xs = self._map_dcl
        if dcl <= xs[0]:
            return self._map_cmu[0]
        if dcl >= xs[-1]:
            return self._map_cmu[-1]
        j = bisect_right(xs, dcl) - 1
        c0, c1 = self._map_cmu[j], self._map_cmu[j + 1]
        return c0 + (c1 - c0) * (dcl - xs[j]) / (xs[j + 1] - xs[j])

    def step(self, estimate: Any, reference: float) -> float:
        """One sample: the observer's estimate (an :class:`~rtlift.observer.Estimate` or ΔĈL
        as a float) and the ΔCL reference; returns the envelope Cμ to command. A new one is
        decided every ``period`` samples (``updated``); in between the last is returned."""
        dcl = estimate if isinstance(estimate, float) else estimate.dcl
        if dcl == dcl:  # a NaN estimate (no measurement yet) does not feed the average
            self._err_sum += reference - dcl
            self._est_sum += dcl
            self._point = dcl
            self._n += 1
        self._ref_sum += reference
        self._ref_n += 1
        self._count += 1
        if self._count < self.config.period:
            self.updated = False
            return self.envelope
        cfg = self.config
        ref = self._ref_sum / self._ref_n
        self.feedforward = self.inverse(ref)
        v = ref
        if cfg.feedback and self._n and self._youla:
            v = ref + self._youla_step(self._err_sum / self._n, ref - self._point, ref)
        elif cfg.feedback and self._n:
            if self._rows:
                self._schedule_at(self.feedforward)
            e = self._err_sum / self._n
            e2 = lead_lag(self._e2, e, self._last_e, self._c, self._d, self._g2)   # e itself when c = d = 0
            self._e2 = e2
            self._last_e = e
            err = lead_lag(self._filtered, e2, self._last_err, self._a, self._b, self._g)
            self._filtered = err
            self._last_err = e2
            x = self._est_sum / self._n - self._point
            x2 = lead_lag(self._x2, x, self._last_x, self._c, self._d, self._g2)
            self._x2 = x2
            self._last_x = x
            fast = self.kx * x2
            v = ref + self.kp * err + fast + self.integral
            lo, hi = self.dcl_min, self.dcl_reach
            pushing_high = v >= hi and err > 0.0
            pushing_low = v <= lo and err < 0.0
            if not (pushing_high or pushing_low):  # conditional integration
                self.integral += self._gain_i * err
                span = hi - lo
                self.integral = min(max(self.integral, -span), span)
                v = ref + self.kp * err + fast + self.integral
        self.saturated = v >= self.dcl_reach or v <= self.dcl_min
        if not self._youla:          # the internal-model controller's step sets it exactly (w)
            self.feedback_dcl = min(max(v, self.dcl_min), self.dcl_reach) - ref
        self.envelope = self.inverse(v)
        self._start_period()
        self.updated = True
        return self.envelope

    def _youla_step(self, e_a: float, e_x: float, ref: float) -> float:
        """The internal-model controller's decision (module docstring): w = Σ_i Q_A[i] ê_A[k−i] +
        Q_X[i] ê_X[k−i] with ê = e + Σ_{j≥1} P[j] w[k−j] (the errors corrected by the model's
        response to the controller's own past outputs), w clamped so that r + w stays in the map's
        range and stored as applied (no windup). Returns w (ΔCL)."""
        youla_at(self._youla, self.feedforward, self._taps)
        qa, qx, pa, px = self._taps
        wh, npl = self._w_hist, len(self._w_hist)
        for j in range(1, npl):
            wj = wh[(self._w_pos - j) % npl]
            e_a += pa[j] * wj
            e_x += px[j] * wj
        nq = len(self._ea_hist)
        self._ea_hist[self._e_pos] = e_a
        self._ex_hist[self._e_pos] = e_x
        w = 0.0
        for i in range(nq):
            k = (self._e_pos - i) % nq
            w += qa[i] * self._ea_hist[k] + qx[i] * self._ex_hist[k]
        self._e_pos = (self._e_pos + 1) % nq
        if ref + w > self.dcl_reach:
            w = self.dcl_reach - ref
        elif ref + w < self.dcl_min:
            w = self.dcl_min - ref
        wh[self._w_pos] = w
        self._w_pos = (self._w_pos + 1) % npl
        self.feedback_dcl = w
        return w

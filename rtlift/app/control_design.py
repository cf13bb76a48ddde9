"""The lift loop's feedback designed from the identified model with python-control.

The loop :class:`~rtlift.app.control.LiftController` closes runs at the burst rate: every
``period`` samples (8 Hz) it takes the estimate's mean over the last period (the window ends
``margin`` samples before the next burst onset) and its latest value, decides an envelope,
and the firmware latches it at that onset and holds it for one period. Seen from the
controller's ΔCL-valued output ``v`` (before the inverse static map) to each of the two
measurements, the plant is an exact discrete-time system at the burst period T (a lifted
system):

    P_A(Z) = Σ_j p_j Z⁻ʲ,   p_j = ∂ ⟨ΔCL⟩_window j / ∂ v_0
    P_X(Z) = Σ_j q_j Z⁻ʲ,   q_j = ∂ ΔCL(end of window j) / ∂ v_0

linearised at the operating point ΔCL₀ = S(Cμ₀): the model's response (the Wiener LTI with the
static map's local gain, the high-passed burst convolution with its ripple, the input stages)
to a small one-period pulse of ``v`` through the controller's own inverse map, bursts on at
every onset (central differences, ±2 %). The hold (one period from the onset), the margin
and the window are all in it; ``p_0 = q_0 = 0`` (the window ends before the onset). In ΔCL
units ``Σ p_j`` ≈ 1 at every operating point; what changes
with Cμ is the shape (the burst convolution is linear in Cμ while the map's slope falls 2–5×
over its range), hence a gain schedule over Cμ.

The observer is left out of the loop gain: with the model as plant its estimate responds to
the envelope exactly as the model does, and a lift disturbance passes into the estimate
through the bias state, whose bandwidth (≈ 9 Hz on the bench model) is far above the loop's.

The feedback, in ΔCL per ΔCL, is PI with a first-order lead–lag on the mean error, plus a
gain K_x on the latest estimate's departure from the mean (no integral on it, so its ripple
offset cannot bias the mean):

    v − r = C(Z) e_A + K_x (e_X − e_A),   C(Z) = (K_p + K_i Z/(Z − 1)) · g (Z − a)/(Z − b),
    g = (1 − b)/(1 − a),   K_i = T / T_i,   loop gain  L = C P_A + K_x (P_X − P_A)

The latest value is half a period fresher than the mean: with it the rejection bandwidth the
model predicts at |S| ≤ 3 dB goes from ≈ 0.19 Hz (mean only, one lead–lag) to ≈ 0.30 Hz.

chosen by a seeded global search (``scipy.optimize.differential_evolution``, then Nelder–Mead
from its best and from the neighbouring point's gains) for the widest
disturbance-rejection bandwidth — the highest frequency f₆ below which the predicted
sensitivity |S| = |1/(1 + L)| stays ≤ 0.5 (6 dB of suppression) — subject to a stable
closed loop, gain margin ≥ ``gm_db``, phase margin ≥ ``pm_deg``, max |S| ≤ ``peak_db``
(the amplification allowed anywhere) and a bounded controller gain at 4 Hz (no burst-to-burst
chatter of the envelope). The search evaluates the loop on a frequency grid;
python-control (``stability_margins``, ``feedback(...).poles()``) checks the result.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from rtlift.app.control import BURST_PERIOD_SAMPLES, ControlConfig, LiftController

MARGIN_SAMPLES = 10
"""Decisions fall this many samples before the next burst onset (``rtlift.app.closed_loop``)."""
BURST_S = 0.01
"""Δt_b: one burst (4 samples at 400 Hz)."""
LIFT_PERIODS = 16
"""Length of the lifted impulse response (2 s at 8 Hz; the bench model's is below 1 % of its
peak after 1.2 s)."""
SCHEDULE_FRACTIONS = (0.15, 0.5, 0.85)
"""Operating points of the gain schedule, as fractions of the static map's ΔCL range."""
F_GRID = np.geomspace(0.01, 3.99, 500)
"""Frequencies (Hz) on which the search evaluates the loop (up to the 4 Hz Nyquist rate)."""
BOUNDS = ((0.0, 4.0), (0.1, 2.0), (-0.9, 0.95), (0.0, 0.95), (-1.0, 3.0))
"""Search box of (K_p, K_i, a, b, K_x). K_i ≥ 0.1 (T_i ≤ 1.25 s) keeps the integral fast enough
for slow drifts (an actuator fade). The lag pole b stays on the positive axis: a pole near
Z = −1 would amplify the estimate's noise at the burst rate's Nyquist frequency (4 Hz), an
envelope alternating from one burst to the next."""
HAND_START = (0.5, 0.5, 0.0, 0.0, 0.0)
"""Where the search starts at the first operating point: the hand-set PI (K_p 0.5, T_i 0.25 s)."""
NYQUIST_GAIN_MAX = 2.0
"""Largest gain |C(−1) − K_x| + |K_x| from the estimate to ``v`` at 4 Hz (ΔCL per ΔCL): bounds
the envelope's burst-to-burst chatter from the estimate's noise."""


@dataclass(frozen=True)
class Targets:
    """Design targets: gain margin (dB), phase margin (deg), largest predicted |S| anywhere (dB).

    ``peak_db`` 4: the goal is at most 3 dB of amplification of the *measured* lift, and the
    bench-identified model over-predicts the bench's loop gain by about 1.5 dB at ΔCL 0.08
    (measured suppression 1–2 dB weaker than predicted below 0.5 Hz, amplification 1–1.6 dB
    smaller near 1 Hz; docs/results/control.md): a design to a predicted 4 dB measured +1.9 dB,
    one to a predicted 3 dB measured +1.6 dB with a 6 dB band of 0.26 Hz instead of 0.35 Hz."""

    gm_db: float = 6.0
    pm_deg: float = 45.0
    peak_db: float = 4.0


@dataclass(frozen=True)
class Gains:
    """C(Z) = (kp + ki Z/(Z − 1)) · g (Z − a)/(Z − b) and K_x (module docstring), ΔCL per ΔCL."""

    kp: float
    ki: float
    a: float = 0.0
    b: float = 0.0
    kx: float = 0.0

    def tf(self, dt: float) -> Any:
        """C(Z) as a python-control transfer function with sample time ``dt``."""
        import control as ct

        g = (1.0 - self.b) / (1.0 - self.a)
        return (self.kp + self.ki * ct.tf([1.0, 0.0], [1.0, -1.0], dt)) * ct.tf([g, -g * self.a], [1.0, -self.b], dt)

    def response(self, z: np.ndarray) -> np.ndarray:
        """C(z) at the points ``z``."""
        g = (1.0 - self.b) / (1.0 - self.a)
        return (self.kp + self.ki * z / (z - 1.0)) * g * (z - self.a) / (z - self.b)

    def loop_response(self, z: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """L(z) = C P_A + K_x (P_X − P_A) at the points ``z``."""
        pa, px = plant_response(p, z), plant_response(q, z)
        return self.response(z) * pa + self.kx * (px - pa)

    def nyquist_gain(self) -> float:
        """|C(−1) − K_x| + |K_x|: the gain from the estimate to ``v`` at 4 Hz, bounded."""
        return float(abs(self.response(np.array([-1.0 + 0j]))[0] - self.kx) + abs(self.kx))


@dataclass
class PointDesign:
    """The design at one operating point: the lifted plant, the gains, python-control's margins."""

    cmu: float
    dcl: float
    plant: list[float]
    """p_j: the period's mean."""
    plant_point: list[float]
    """q_j: the latest value."""
    gains: Gains
    gm_db: float
    pm_deg: float
    crossover_hz: float
    peak_s_db: float
    f6_hz: float
    stable: bool

    def loop(self, dt: float) -> Any:
        """L(Z) = C P_A + K_x (P_X − P_A) (python-control)."""
        return loop_tf(self.gains, self.plant, self.plant_point, dt)

    def loop_response(self, f_hz: np.ndarray, dt: float) -> np.ndarray:
        """L(e^{jωT}) at the frequencies ``f_hz`` (complex)."""
        z = np.exp(2j * np.pi * np.asarray(f_hz, dtype=float) * dt)
        return self.gains.loop_response(z, np.asarray(self.plant), np.asarray(self.plant_point))

    def sensitivity(self, f_hz: np.ndarray, dt: float) -> np.ndarray:
        """Predicted S(e^{jωT}) = 1/(1 + L) at the frequencies ``f_hz`` (complex)."""
        return 1.0 / (1.0 + self.loop_response(f_hz, dt))


@dataclass
class Design:
    """The gain-scheduled design: one :class:`PointDesign` per operating point, in Cμ order."""

    points: list[PointDesign]
    dt: float
    period: int
    margin: int
    targets: Targets = field(default_factory=Targets)

    def schedule(self) -> tuple[tuple[float, float, float, float, float, float], ...]:
        """``(Cμ, K_p, T_i s, a, b, K_x)`` rows for :class:`~rtlift.app.control.ControlConfig`."""
        return tuple((p.cmu, p.gains.kp, self.dt / p.gains.ki, p.gains.a, p.gains.b, p.gains.kx)
                     for p in self.points)

    def nearest(self, dcl: float) -> PointDesign:
        """The operating point nearest a ΔCL level."""
        return min(self.points, key=lambda p: abs(p.dcl - dcl))

    def summary(self) -> dict[str, Any]:
        """Worst case over the schedule: margins, peak |S|, f₆."""
        pts = self.points
        gm = min(p.gm_db for p in pts)
        return {"gm_db_min": gm if math.isfinite(gm) else None,  # None: no phase crossover anywhere
                "pm_deg_min": min(p.pm_deg for p in pts),
                "peak_s_db_max": max(p.peak_s_db for p in pts), "f6_hz_min": min(p.f6_hz for p in pts),
                "stable": all(p.stable for p in pts)}

    def to_dict(self) -> dict[str, Any]:
        return {"dt_s": self.dt, "period_samples": self.period, "margin_samples": self.margin,
                "targets": asdict(self.targets), "summary": self.summary(),
                "points": [{**{k: v for k, v in asdict(p).items() if k != "gains"}, "gains": asdict(p.gains),
                            "ti_s": self.dt / p.gains.ki} for p in self.points]}


def plant_tf(p: list[float] | np.ndarray, dt: float) -> Any:
    """P(Z) = Σ_j p_j Z⁻ʲ as a python-control transfer function."""
    import control as ct

    p = np.asarray(p, dtype=float)
    return ct.tf(p, np.r_[1.0, np.zeros(len(p) - 1)], dt)


def loop_tf(g: Gains, p: list[float] | np.ndarray, q: list[float] | np.ndarray, dt: float) -> Any:
    """L(Z) = C P_A + K_x (P_X − P_A) as a python-control transfer function."""
    pa, px = plant_tf(p, dt), plant_tf(q, dt)
    return g.tf(dt) * pa + g.kx * (px - pa)


def plant_response(p: list[float] | np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.polyval(np.asarray(p, dtype=float)[::-1], 1.0 / z)


def lifted_plant(model: Any, controller: LiftController, dcl0: float, *, period: int = BURST_PERIOD_SAMPLES,
                 margin: int = MARGIN_SAMPLES, n_periods: int = LIFT_PERIODS,
                 rel: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(``p_j``, ``q_j``) of the module docstring at ΔCL₀ (the model simulated, central differences)."""
    fs = model.fs_hz
    burst = max(1, int(round(BURST_S * fs)))
    warm = 8 * period * 4                  # 4 s at the operating point first
    n = warm + n_periods * period
    gate = (np.arange(n) % period) < burst
    dv = max(rel * abs(dcl0), 1e-4)
    ys = []
    for v in (dcl0 + dv, dcl0 - dv):
        env = np.full(n, controller.inverse(dcl0))
        env[warm:warm + period] = controller.inverse(v)
        m = model.copy()
        m.reset()
        ys.append(np.asarray(m.simulate(np.where(gate, env, 0.0), env).total))
    y = (ys[0] - ys[1]) / (2.0 * dv)
    ends = warm + np.arange(n_periods) * period - margin + 1   # window j: [end − period, end)
    return np.array([y[e - period:e].mean() for e in ends]), y[ends - 1].copy()


def _grid_metrics(g: Gains, p: np.ndarray, q: np.ndarray, z: np.ndarray,
                  f: np.ndarray) -> tuple[float, float, float, float]:
    """(GM dB, PM deg, peak |S| dB, f₆ Hz) on the grid (the search's fast estimate)."""
    L = g.loop_response(z, p, q)
    mag = np.abs(L)
    cross = np.flatnonzero(np.diff(np.sign(mag - 1.0)))
    pm = min((180.0 - abs(math.degrees(np.angle(L[k]))) for k in cross), default=180.0)
    flips = np.flatnonzero(np.diff(np.sign(L.imag)))
    gm = min((-20.0 * math.log10(abs(L[k].real)) for k in flips if L[k].real < 0), default=math.inf)
    s = np.abs(1.0 / (1.0 + L))
    return gm, pm, 20.0 * math.log10(s.max()), _first_crossing(f, s, 0.5)


def _first_crossing(f: np.ndarray, s: np.ndarray, level: float) -> float:
    """The frequency where ``s`` first rises above ``level``, interpolated in log f (continuous
    in the gains, which the search needs); 0 if it starts above, the grid's end if it never does."""
    above = s > level
    if not above.any():
        return float(f[-1])
    k = int(np.argmax(above))
    if k == 0:
        return 0.0
    w = (level - s[k - 1]) / (s[k] - s[k - 1])
    return float(np.exp(np.log(f[k - 1]) + w * (np.log(f[k]) - np.log(f[k - 1]))))


def _stable(g: Gains, p: np.ndarray, q: np.ndarray) -> bool:
    """Closed-loop poles inside the unit circle: the roots of
    D_C Z^{n−1} + N_C Σ p_j Z^{n−1−j} + K_x D_C Σ (q_j − p_j) Z^{n−1−j},  C = N_C / D_C."""
    n = len(p)
    gain = (1.0 - g.b) / (1.0 - g.a)
    c_num = gain * np.polymul([g.kp + g.ki, -g.kp], [1.0, -g.a])
    c_den = np.polymul([1.0, -1.0], [1.0, -g.b])
    char = np.polyadd(np.polyadd(np.polymul(c_den, np.r_[1.0, np.zeros(n - 1)]), np.polymul(c_num, p)),
                      np.polymul(c_den, g.kx * (q - p)))
    return bool(np.all(np.abs(np.roots(char)) < 1.0 - 1e-9))


def design_point(p: np.ndarray, q: np.ndarray, dt: float, targets: Targets, seed: int = 1,
                 start: Gains | None = None) -> Gains:
    """The gains that maximise f₆ under the targets (module docstring); ``start`` seeds the
    search (the neighbouring operating point's gains: a smooth schedule)."""
    from scipy.optimize import differential_evolution, minimize

    z = np.exp(2j * np.pi * F_GRID * dt)

    def cost(x: np.ndarray) -> float:
        g = Gains(*map(float, x))
        if not _stable(g, p, q):
            return 10.0
        gm, pm, peak, f6 = _grid_metrics(g, p, q, z, F_GRID)
        nyquist = g.nyquist_gain()
        return (-f6 + max(0.0, targets.gm_db + 0.2 - gm) + max(0.0, targets.pm_deg + 1.0 - pm) / 10.0
                + 2.0 * max(0.0, peak - targets.peak_db + 0.1) + max(0.0, nyquist - NYQUIST_GAIN_MAX))

    lo, hi = np.array(BOUNDS).T
    x0 = np.array([start.kp, start.ki, start.a, start.b, start.kx] if start is not None else HAND_START)
    res = differential_evolution(cost, BOUNDS, seed=seed, maxiter=60, popsize=10, tol=1e-10, polish=False, x0=x0)
    best = min((minimize(lambda x: cost(np.clip(x, lo, hi)), x, method="Nelder-Mead",
                         options={"maxiter": 600, "xatol": 1e-4, "fatol": 1e-6}) for x in (res.x, x0)),
               key=lambda r: r.fun)
    return Gains(*map(float, np.clip(best.x, lo, hi)))


def check_point(cmu: float, dcl: float, p: np.ndarray, q: np.ndarray, g: Gains, dt: float) -> PointDesign:
    """Margins and crossover from python-control; peak |S| and f₆ on a fine grid."""
    import control as ct

    L = loop_tf(g, p, q, dt)
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)   # L at z = 1 (the integrator): no stderr line
        gm, pm, _, _, wgc, _ = ct.stability_margins(L)
        stable = bool(np.all(np.abs(ct.feedback(L, 1).poles()) < 1.0))
    f = np.geomspace(0.005, 0.5 / dt - 1e-3, 2000)
    z = np.exp(2j * np.pi * f * dt)
    _, _, peak, f6 = _grid_metrics(g, p, q, z, f)
    gm_db = 20.0 * math.log10(gm) if np.isfinite(gm) else math.inf
    return PointDesign(cmu, dcl, [float(v) for v in p], [float(v) for v in q], g, gm_db,
                       float(pm), float(wgc) / (2.0 * math.pi), peak, f6, stable)


def design_loop(model: Any, targets: Targets | None = None, config: ControlConfig | None = None,
                fractions: tuple[float, ...] = SCHEDULE_FRACTIONS) -> Design:
    """The gain-scheduled design for ``model`` (module docstring)."""
    targets = targets or Targets()
    cfg = config or ControlConfig(fs_hz=model.fs_hz)
    ctl = LiftController(model, cfg)
    dt = cfg.period / cfg.fs_hz
    points: list[PointDesign] = []
    for frac in fractions:
        dcl0 = ctl.dcl_min + frac * (ctl.dcl_max - ctl.dcl_min)
        p, q = lifted_plant(model, ctl, dcl0, period=cfg.period)
        g = design_point(p, q, dt, targets, start=points[-1].gains if points else None)
        points.append(check_point(ctl.inverse(dcl0), dcl0, p, q, g, dt))
    return Design(points, dt, cfg.period, MARGIN_SAMPLES, targets)


def schedule_from_report(path: str) -> tuple[tuple[float, float, float, float, float, float], ...]:
    """The schedule rows ``(Cμ, K_p, T_i, a, b, K_x)`` of a saved design (``rtlift design``'s
    report.json); :class:`~rtlift.core.errors.UserError` (one line) if it is not one."""
    import json

    from rtlift.core.errors import UserError

    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
        rows = tuple((float(p["cmu"]), float(p["gains"]["kp"]), float(p["ti_s"]), float(p["gains"]["a"]),
                      float(p["gains"]["b"]), float(p["gains"]["kx"])) for p in doc["points"])
        ControlConfig(schedule=rows)
    except OSError as exc:
        raise UserError(f"--design {path}: cannot read it ({exc.strerror or exc})") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f"--design {path}: not a design report of rtlift design ({exc})") from None
    if not rows:
        raise UserError(f"--design {path}: the report has no operating points")
    return rows

"""A single-input model of the paper's W-block family, for any system (generic ``t,u,y`` records).

    x(k) = G₁(q) u(k),   v(k) = f(x(k)),   y(k) = G₂(q) v(k)

G₁ and G₂ are stable transfer functions run as second-order sections (the streaming SOS block
of :mod:`rtlift.blocks.highpass`, sosfilt-compatible state), f a piecewise-linear static map
on knots with linear extrapolation (:class:`rtlift.blocks.wiener.OutputNonlinearity`). With
G₂ = 1 this is the textbook Wiener model (the paper's W block in its textbook form); with G₂
it is Wiener–Hammerstein (the ``output_dynamics`` structure the diagnosis adds). The gain
ambiguity is fixed by G₁(1) = 1: f carries the static gain.

:meth:`SisoModel.step` is one sample (no allocation); :meth:`SisoModel.simulate` its batch
twin; both carry one explicit state. A model file is JSON with ``"kind": "siso"``
(:mod:`rtlift.model.siso_file`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rtlift.blocks.chain import BlockChain
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import OutputNonlinearity
from rtlift.core.jit import njit_cached
from rtlift.core.registry import LIMIT_FORMS, MODEL_STRUCTURE_NAMES, MODEL_STRUCTURES

FORMAT = "rtlift-siso-model"
VERSION = 1
"""The file form every model here writes with ``to_dict`` (:mod:`rtlift.model.siso_file` reads it)."""


def _finite(v: float) -> float | None:
    """A limit as the file form gives it: ``None`` for an infinite one."""
    return float(v) if np.isfinite(v) else None


def _limit_pair(sat: dict[str, Any]) -> tuple[float, float]:
    """(lower, upper) of a file form's ``saturation``, ``None`` read as infinite."""
    lo, hi = sat.get("lower"), sat.get("upper")
    return -np.inf if lo is None else float(lo), np.inf if hi is None else float(hi)

STRUCTURES = MODEL_STRUCTURE_NAMES
"""The structures a generic record is identified in (:data:`rtlift.core.registry.MODEL_STRUCTURES`)."""
LIMITED: dict[str, tuple[str, ...]] = {where: tuple(s for s, at in LIMIT_FORMS if at == where)
                                       for where in ("output", "state")}
"""Where a limit is built, and in which structures: the registry's ``saturation`` forms."""


def listed(names: tuple[str, ...]) -> str:
    """``a, b and c``."""
    return " and ".join(filter(None, (", ".join(names[:-1]), names[-1])))


INTEGRATOR = (np.array([1.0]), np.array([1.0, -(1.0 - 1e-12)]))
"""1/(1 − ρq⁻¹), ρ = 1 − 10⁻¹²: the last block of a model fitted on the differenced output and run
integrated (:mod:`rtlift.sysid.identify`, 5); the streaming filter takes poles inside the unit
circle only, and this one leaks 0.1 % over 10⁹ samples."""
_INTEGRATOR_SOS = HighPassFilter.from_ba(*INTEGRATOR).sos


@dataclass(eq=False)
class SisoModel(BlockChain):
    g1: HighPassFilter
    f: OutputNonlinearity
    g2: HighPassFilter | None
    fs_hz: float
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def integrating(self) -> bool:
        """Whether G₂ is :data:`INTEGRATOR` alone: a Wiener model of the differenced output, run
        integrated (its structure is ``wiener``: the diagnosis tries what a Wiener model lacks on it)."""
        return self.g2 is not None and np.array_equal(self.g2.sos, _INTEGRATOR_SOS)

    @property
    def structure(self) -> str:
        return "wiener" if self.g2 is None or self.integrating else "wiener_hammerstein"

    @property
    def blocks(self) -> tuple:
        return (self.g1,) if self.g2 is None else (self.g1, self.g2)

    def step(self, u: float) -> float:
        v = self.f.step(0.0, self.g1.step(u))
        return v if self.g2 is None else self.g2.step(v)

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """Batch twin of :meth:`step`; starts from and advances the current state."""
        v = self.f.simulate(None, self.g1.simulate(np.asarray(u, dtype=float)))
        return v if self.g2 is None else self.g2.simulate(v)

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "version": VERSION, "kind": "siso", "structure": self.structure,
                "fs_hz": self.fs_hz, "g1_sos": self.g1.sos.tolist(),
                "f": {"x": self.f.y.tolist(), "y": self.f.f.tolist()},
                "g2_sos": None if self.g2 is None else self.g2.sos.tolist(),
                "provenance": self.provenance, "metrics": self.metrics}

    def copy(self) -> SisoModel:
        """The same model, its own blocks (the same coefficients, a zero state)."""
        return type(self)(HighPassFilter(self.g1.sos.copy()), OutputNonlinearity(self.f.y.copy(), self.f.f.copy()),
                          None if self.g2 is None else HighPassFilter(self.g2.sos.copy()), self.fs_hz,
                          dict(self.provenance), dict(self.metrics))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SisoModel:
        """From its file form (:func:`~rtlift.model.siso_file.model_from_dict`; KeyError, TypeError or
        ValueError if wrong)."""
        g1 = HighPassFilter(np.asarray(d["g1_sos"], dtype=float))
        f = OutputNonlinearity(d["f"]["x"], d["f"]["y"])
        g2 = None if d.get("g2_sos") is None else HighPassFilter(np.asarray(d["g2_sos"], dtype=float))
        fs = float(d["fs_hz"])
        if not np.isfinite(fs) or fs <= 0:
            raise ValueError("fs_hz must be a positive number")
        return cls(g1, f, g2, fs, dict(d.get("provenance") or {}), dict(d.get("metrics") or {}))


class FeedbackModel:
    """The output fed back through a static map into a linear block's input (``nonlinear_feedback``;
    Silverbox: an electronic Duffing oscillator, m ÿ + d ẏ + k y + k₃ y³ = u):

        y(k) = Σ_{i=1..n} b_i v(k−i) − Σ_{i=1..n} a_i y(k−i),   v(k) = u(k) − k₂ y(k)² − k₃ y(k)³

    G = B/A strictly proper, so y(k) needs no v(k) (no algebraic loop). ``offset`` c is the
    output's operating point: the model outputs c + y(k), the map and the recursion act on the
    deviation y from it (a spring's rest position that is not the sensor's zero; 0 in files
    written before it existed). ``feedthrough`` b₀ adds b₀ u(k) to y(k): the input's direct
    path, known at sample k, so still no algebraic loop (0 in files written before it existed). The feedback makes the
    response amplitude dependent (the resonance shifts with amplitude); it cannot be filtered
    in one vectorised pass, so :meth:`simulate` runs the same recursion as :meth:`step` over the
    array (identical by construction). State: [y(k−1) … y(k−n), v(k−1) … v(k−n)].

    ``state_limits`` (lower, upper) is a limit on the state (``saturation`` where ``state``), in
    output units: y(k) is clipped inside the recursion, before it is stored and fed back,

        y(k) = min(max(Σ b_i v(k−i) − Σ a_i y(k−i), lower − c), upper − c),

    a store that cannot fill beyond its brim (Cascaded Tanks: the lower tank overflows, its
    level stays at the brim and falls as soon as the inflow does), where an output limit
    would let the unclipped level wind up beyond it and lag on the way down.

    ``friction`` (k₀, k_c, s) adds a constant and a smoothed sign to the map,

        v(k) = u(k) − k₂ y(k)² − k₃ y(k)³ − k₀ − k_c tanh(y(k)/s),

    a force the input works against (an offset, Coulomb friction; the viscous part is the linear
    block's own damping). ``integrating``: the recursion's y is the differenced output (a
    velocity, output units per sample) and the model outputs its running sum,
    c + p(k), p(k) = p(k−1) + y(k) (a position: EMPS's force in, position out); the state gains
    p, last. Neither is written to the file while unused (files as before).

    ``hysteresis`` (α, g, d) adds a Bouc–Wen state z (a force, the input's units) to the map:
    Noël & Schoukens' hysteretic benchmark, m ÿ + c ẏ + k y + z = u, ż = α ẏ − β(γ|ẏ||z|^(ν−1)z +
    δ ẏ|z|^ν), at ν = 1 (g = βγ, d = βδ, per output unit). The recursion then runs ``substeps`` M
    times per sample (B/A a linear block at M fs, the input held over the sample as a ZOH), each
    substep j coupling z to the output's increment h = y − y_prev by the trapezoidal rule:

        r = Σ b_i v(j−i) − Σ a_i y(j−i),   κ = α − g sgn(r − y_prev) z − d |z|,
        h = (r − y_prev) / (1 + b₁κ/2),   z_new = z + κ h,   y = y_prev + h,
        v(j−1) ← v(j−1) − (z_new − z)/2,   v(j) = u_held − k₂y² − k₃y³ − z_new,

    (the force over the substep just ended is the input less the mean of z at its two ends;
    u_held the previous sample's input but on the last substep, the present one). The output is
    c + y of the last substep; the state is [y…, v…, z, u_prev] (the histories at M fs). Euler in
    y with z fed a substep late, at M = 1, erred 34 µm on the simulated benchmark's held-out data
    from the true parameters refined; this form at M = 4, 10.6 µm (its noise 8 µm). Not with a
    limit, ``integrating``, friction or a feedthrough; not written to the file while unused (its
    key ``bouc_wen``: ``hysteresis`` names a lift effect).
    """

    structure = "nonlinear_feedback"

    def __init__(self, a: np.ndarray, b: np.ndarray, feedback: np.ndarray, fs_hz: float,
                 provenance: dict[str, Any] | None = None, metrics: dict[str, Any] | None = None,
                 state_limits: tuple[float, float] = (-np.inf, np.inf), offset: float = 0.0,
                 feedthrough: float = 0.0, friction: tuple[float, float, float] = (0.0, 0.0, 1.0),
                 integrating: bool = False, hysteresis: tuple[float, float, float] | None = None,
                 substeps: int = 1) -> None:
        a, b, k = (np.asarray(v, dtype=float).ravel() for v in (a, b, feedback))
        if a.size != b.size or a.size == 0 or k.size != 2 or not all(np.all(np.isfinite(v)) for v in (a, b, k)):
            raise ValueError("nonlinear_feedback needs finite a, b of one length and two feedback coefficients")
        self.offset, self.b0 = float(offset), float(feedthrough)
        if not (np.isfinite(self.offset) and np.isfinite(self.b0)):
            raise ValueError(f"nonlinear_feedback needs a finite offset and feedthrough, got {offset}, {feedthrough}")
        self.a, self.b, self.k = a, b, k
        self.n = a.size
        self.fs_hz = float(fs_hz)
        self.provenance, self.metrics = dict(provenance or {}), dict(metrics or {})
        self._a, self._b = a.tolist(), b.tolist()
        self._k2, self._k3 = float(k[0]), float(k[1])
        lo, hi = (float(v) for v in state_limits)
        if np.isnan(lo) or np.isnan(hi) or not lo < hi:
            raise ValueError(f"state limits need lower < upper, got {lo}, {hi}")
        self.state_limits = (lo, hi)
        self._lo, self._hi = lo - self.offset, hi - self.offset     # on the deviation y
        k0, kc, scale = (float(v) for v in friction)
        if not (np.isfinite(k0) and np.isfinite(kc) and np.isfinite(scale) and scale > 0):
            raise ValueError(f"nonlinear_feedback needs a finite friction (k0, kc) and scale > 0, got {friction}")
        self.friction, self.integrating = (k0, kc, scale), bool(integrating)
        if self.integrating and self.limited:
            raise ValueError("an integrating nonlinear_feedback model takes no state limit")
        self._y = [0.0] * self.n
        self._v = [0.0] * self.n
        self._p = 0.0
        self.hysteresis = None if hysteresis is None else tuple(float(v) for v in hysteresis)
        self.substeps = int(substeps)
        self._z = self._u = 0.0
        if self.hysteresis is not None:
            if len(self.hysteresis) != 3 or not all(np.isfinite(self.hysteresis)) or self.substeps < 1:
                raise ValueError(f"nonlinear_feedback needs a finite hysteresis (alpha, g, d) and substeps >= 1, "
                                 f"got {hysteresis}, {substeps}")
            if self.integrating or self.limited or self.b0 != 0.0 or self.friction != (0.0, 0.0, 1.0):
                raise ValueError("a hysteretic nonlinear_feedback model takes no limit, integration, friction or "
                                 "feedthrough")

    @property
    def hysteretic(self) -> bool:
        """Whether the map holds a Bouc–Wen state (``hysteresis``)."""
        return self.hysteresis is not None

    @property
    def limited(self) -> bool:
        """Whether the state is limited (``saturation`` where ``state``)."""
        return bool(np.isfinite(self._lo) or np.isfinite(self._hi))

    state_size = property(lambda self: 2 * self.n + self.integrating + 2 * self.hysteretic)

    def _hysteretic_step(self, u: float) -> float:
        """One sample of the hysteretic recursion (class docstring), ``substeps`` substeps."""
        yh, vh, a, b = self._y, self._v, self._a, self._b
        al, g, d = self.hysteresis
        z, last = self._z, self.substeps - 1
        y = yh[0]
        for j in range(self.substeps):
            r = 0.0
            for i in range(self.n):
                r += b[i] * vh[i] - a[i] * yh[i]
            dr = r - yh[0]
            s = 1.0 if dr >= 0.0 else -1.0
            kap = al - g * s * z - d * abs(z)
            h = dr / (1.0 + 0.5 * b[0] * kap)
            zn = z + kap * h
            y = yh[0] + h
            vh[0] -= 0.5 * (zn - z)
            z = zn
            for i in range(self.n - 1, 0, -1):
                yh[i], vh[i] = yh[i - 1], vh[i - 1]
            yh[0] = y
            vh[0] = (u if j == last else self._u) - self._k2 * y * y - self._k3 * y * y * y - z
        self._z, self._u = z, u
        return self.offset + y

    def step(self, u: float) -> float:
        if self.hysteresis is not None:
            return self._hysteretic_step(u)
        yh, vh = self._y, self._v
        y = self.b0 * u
        for i in range(self.n):
            y += self._b[i] * vh[i] - self._a[i] * yh[i]
        y = min(max(y, self._lo), self._hi)
        k0, kc, scale = self.friction
        v = u - self._k2 * y * y - self._k3 * y * y * y - k0 - kc * math.tanh(y / scale)
        for i in range(self.n - 1, 0, -1):
            yh[i], vh[i] = yh[i - 1], vh[i - 1]
        yh[0], vh[0] = y, v
        if self.integrating:
            self._p += y
            return self.offset + self._p
        return self.offset + y

    def simulate(self, u: np.ndarray) -> np.ndarray:
        """:meth:`step` over ``u``, compiled (:func:`_feedback_run`: the same arithmetic in the same
        order), the state carried on."""
        u = np.ascontiguousarray(u, dtype=float)
        out = np.empty(u.size)
        if self.hysteresis is not None:
            yh, vh, zu = np.array(self._y), np.array(self._v), np.array([self._z, self._u])
            _hysteretic_run(self.a, self.b, self._k2, self._k3, self.offset, np.array(self.hysteresis), self.substeps,
                            u, yh, vh, zu, out)
            self._y[:], self._v[:], self._z, self._u = yh.tolist(), vh.tolist(), float(zu[0]), float(zu[1])
            return out
        yh, vh, p = np.array(self._y), np.array(self._v), np.array([self._p])
        _feedback_run(self.a, self.b, self._k2, self._k3, self._lo, self._hi, self.offset, self.b0,
                      np.array(self.friction), self.integrating, u, yh, vh, p, out)
        self._y[:], self._v[:], self._p = yh.tolist(), vh.tolist(), float(p[0])
        return out

    def reset(self) -> None:
        self._y[:] = [0.0] * self.n
        self._v[:] = [0.0] * self.n
        self._p = self._z = self._u = 0.0

    def get_state(self) -> np.ndarray:
        return np.array(self._y + self._v + ([self._p] if self.integrating else [])
                        + ([self._z, self._u] if self.hysteretic else []))

    @property
    def accumulator(self) -> int | None:
        """The index in the state of the running sum the output is shifted by one for one
        (``integrating``), else ``None`` (:func:`rtlift.sysid.initial.initial_state`)."""
        return 2 * self.n if self.integrating else None

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"model state must have shape ({self.state_size},), got {s.shape}")
        self._y[:], self._v[:] = s[:self.n].tolist(), s[self.n:2 * self.n].tolist()
        if self.integrating:
            self._p = float(s[-1])
        if self.hysteretic:
            self._z, self._u = float(s[-2]), float(s[-1])

    def limits(self) -> dict[str, Any]:
        """The state limit as the report and the file give it (infinite sides as ``None``)."""
        lo, hi = self.state_limits
        return {"lower": _finite(lo), "upper": _finite(hi), "where": "state"}

    def to_dict(self) -> dict[str, Any]:
        d = {"format": FORMAT, "version": VERSION, "kind": "siso", "structure": self.structure,
             "fs_hz": self.fs_hz, "a": self.a.tolist(), "b": self.b.tolist(), "feedback": self.k.tolist(),
             "offset": self.offset, "feedthrough": self.b0, "provenance": self.provenance, "metrics": self.metrics}
        if self.integrating or self.friction != (0.0, 0.0, 1.0):
            d |= {"friction": list(self.friction), "integrating": self.integrating}
        if self.hysteretic:
            d |= {"bouc_wen": list(self.hysteresis), "substeps": self.substeps}
        return {**d, "saturation": self.limits()} if self.limited else d

    def copy(self) -> FeedbackModel:
        """The same model (coefficients, limits, offset, feedthrough, friction, hysteresis), a zero state."""
        return FeedbackModel(self.a.copy(), self.b.copy(), self.k.copy(), self.fs_hz, self.provenance, self.metrics,
                             self.state_limits, self.offset, self.b0, self.friction, self.integrating,
                             self.hysteresis, self.substeps)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FeedbackModel:
        """From its file form, a state limit its own (:func:`~rtlift.model.siso_file.model_from_dict`; KeyError,
        TypeError or ValueError if wrong; a file without ``offset``, written before it existed, has none)."""
        sat = d.get("saturation")
        return cls(d["a"], d["b"], d["feedback"], float(d["fs_hz"]), d.get("provenance"), d.get("metrics"),
                   _limit_pair(sat) if sat is not None else (-np.inf, np.inf), float(d.get("offset", 0.0)),
                   float(d.get("feedthrough", 0.0)), tuple(d.get("friction", (0.0, 0.0, 1.0))),
                   bool(d.get("integrating", False)), d.get("bouc_wen"), int(d.get("substeps", 1)))


@njit_cached
def _feedback_run(a: np.ndarray, b: np.ndarray, k2: float, k3: float, lo: float, hi: float, c: float, b0: float,
                  friction: np.ndarray, integrating: bool, u: np.ndarray, yh: np.ndarray, vh: np.ndarray,
                  p: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover
    """:meth:`FeedbackModel.step` over ``u`` (compiled; the same arithmetic in the same order),
    advancing the histories ``yh``, ``vh`` (newest first) and the running sum ``p[0]`` in place."""
    n = a.size
    k0, kc, scale = friction[0], friction[1], friction[2]
    for k in range(u.size):
        y = b0 * u[k]
        for i in range(n):
            y += b[i] * vh[i] - a[i] * yh[i]
        y = min(max(y, lo), hi)
        v = u[k] - k2 * y * y - k3 * y * y * y - k0 - kc * math.tanh(y / scale)
        for i in range(n - 1, 0, -1):
            yh[i] = yh[i - 1]
            vh[i] = vh[i - 1]
        yh[0] = y
        vh[0] = v
        if integrating:
            p[0] += y
            out[k] = c + p[0]
        else:
            out[k] = c + y


@njit_cached
def _hysteretic_run(a: np.ndarray, b: np.ndarray, k2: float, k3: float, c: float, hyst: np.ndarray, substeps: int,
                    u: np.ndarray, yh: np.ndarray, vh: np.ndarray, zu: np.ndarray,
                    out: np.ndarray) -> None:   # pragma: no cover
    """:meth:`FeedbackModel._hysteretic_step` over ``u`` (compiled; the same arithmetic in the same
    order), advancing the histories ``yh``, ``vh`` (newest first) and ``zu`` = [z, u_prev] in place."""
    n = a.size
    al, g, d = hyst[0], hyst[1], hyst[2]
    z, up, last = zu[0], zu[1], substeps - 1
    for k in range(u.size):
        y = yh[0]
        for j in range(substeps):
            r = 0.0
            for i in range(n):
                r += b[i] * vh[i] - a[i] * yh[i]
            dr = r - yh[0]
            s = 1.0 if dr >= 0.0 else -1.0
            kap = al - g * s * z - d * abs(z)
            h = dr / (1.0 + 0.5 * b[0] * kap)
            zn = z + kap * h
            y = yh[0] + h
            vh[0] -= 0.5 * (zn - z)
            z = zn
            for i in range(n - 1, 0, -1):
                yh[i] = yh[i - 1]
                vh[i] = vh[i - 1]
            yh[0] = y
            vh[0] = (u[k] if j == last else up) - k2 * y * y - k3 * y * y * y - z
        up = u[k]
        out[k] = c + y
    zu[0], zu[1] = z, up


@njit_cached
def _chain_run(p: np.ndarray, u: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover
    """:meth:`StoreChainModel.step` over ``u`` (compiled; the same arithmetic in the same order),
    advancing the state ``x`` = [x₁, x₂] in place; ``p`` as :attr:`StoreChainModel.vector`."""
    b, a1, p1, r, a2, p2, l1, l2, beta, c, top, h, nsub = p
    x1, x2 = x[0], x[1]
    for k in range(u.size):
        out[k] = min(x2 + c, top)
        for _ in range(int(nsub)):
            q1 = a1 * max(x1, 0.0) ** p1
            x1n = x1 + h * (b * u[k] - q1)
            spill = max(x1n - l1, 0.0)
            x1 = min(max(x1n, 0.0), l1)
            x2 = min(max(x2 + h * (r * q1 - a2 * max(x2, 0.0) ** p2) + beta * spill, 0.0), l2)
    x[0], x[1] = x1, x2


class StoreChainModel:
    """Two stores in cascade, each emptied through a static power-law outflow (``store_chain``;
    Cascaded Tanks: a pump fills an upper tank that drains through an orifice into a lower one,
    Torricelli's outflow a·√level):

        ẋ₁ = b u − q₁,   q₁ = a₁ max(x₁, 0)^p₁
        ẋ₂ = r q₁ − a₂ max(x₂, 0)^p₂,   y = x₂ + c

    integrated by explicit Euler in ``substeps`` steps of h = 1/(fs · substeps) per sample, u held
    (zero-order hold), y(k) the level before sample k's update (strictly proper). It is the
    nonlinear-feedback idea applied to each state: every store's outflow is a static map of its
    own level, fed back. A store cannot fill beyond its brim (``saturation`` where ``state``):
    x₁ ≤ L₁, and what would rise above L₁ spills, a share β of it into the lower store
    (x₂ += β · spill); x₂ ≤ L₂ = ``ceiling`` − c, so y stays at most ``ceiling`` (the lower tank
    overflows at the level the measurement piles up at; y = min(x₂ + c, ``ceiling``) exactly, not
    one rounding above it); levels stay ≥ 0. x₁'s scale is not observable (b, a₁, L₁, β
    trade against it); every other parameter is. State [x₁, x₂], 0 at rest.

    :meth:`step` is one sample in plain float arithmetic (no allocation); :meth:`simulate` runs
    the same arithmetic compiled (:func:`_chain_run`).
    """

    structure = "store_chain"
    state_size = 2
    NAMES = ("inflow", "outflow_1", "exponent_1", "transfer", "outflow_2", "exponent_2", "brim_1", "ceiling",
             "spill", "offset")

    def __init__(self, params: dict[str, float], fs_hz: float, substeps: int = 2,
                 provenance: dict[str, Any] | None = None, metrics: dict[str, Any] | None = None) -> None:
        try:
            v = [float(np.inf if params[k] is None else params[k]) for k in self.NAMES]
        except KeyError as exc:
            raise ValueError(f"store_chain needs the parameter {exc}") from None
        b, a1, p1, r, a2, p2, l1, ceiling, beta, c = v
        l2 = ceiling - c
        fs, substeps = float(fs_hz), int(substeps)
        if (not all(np.isfinite(x) for x in (b, a1, p1, r, a2, p2, beta, c, fs)) or min(a1, a2, p1, p2) <= 0
                or beta < 0 or not (l1 > 0 and l2 > 0) or fs <= 0 or substeps < 1):
            raise ValueError("store_chain needs finite inflow, transfer, offset, outflows and exponents > 0, "
                             "spill >= 0, brims > 0, fs_hz > 0 and substeps >= 1")
        self.params = dict(zip(self.NAMES, v, strict=True))
        self.fs_hz, self.substeps = fs, substeps
        self.provenance, self.metrics = dict(provenance or {}), dict(metrics or {})
        self.vector = np.array([b, a1, p1, r, a2, p2, l1, l2, beta, c, ceiling, 1.0 / (fs * substeps),
                                float(substeps)])
        self._p = tuple(self.vector.tolist())
        self._x = np.zeros(2)
        self._x1 = self._x2 = 0.0

    @property
    def limited(self) -> bool:
        return bool(np.isfinite(self.params["brim_1"]) or np.isfinite(self.params["ceiling"]))

    def step(self, u: float) -> float:
        b, a1, p1, r, a2, p2, l1, l2, beta, c, top, h, nsub = self._p
        x1, x2 = self._x1, self._x2
        y = min(x2 + c, top)
        for _ in range(int(nsub)):
            q1 = a1 * max(x1, 0.0) ** p1
            x1n = x1 + h * (b * u - q1)
            spill = max(x1n - l1, 0.0)
            x1 = min(max(x1n, 0.0), l1)
            x2 = min(max(x2 + h * (r * q1 - a2 * max(x2, 0.0) ** p2) + beta * spill, 0.0), l2)
        self._x1, self._x2 = x1, x2
        return y

    def simulate(self, u: np.ndarray) -> np.ndarray:
        u = np.ascontiguousarray(u, dtype=float)
        out = np.empty(u.size)
        x = np.array([self._x1, self._x2])
        _chain_run(self.vector, u, x, out)
        self._x1, self._x2 = float(x[0]), float(x[1])
        return out

    def reset(self) -> None:
        self._x1 = self._x2 = 0.0

    def get_state(self) -> np.ndarray:
        return np.array([self._x1, self._x2])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (2,):
            raise ValueError(f"model state must have shape (2,), got {s.shape}")
        self._x1, self._x2 = float(s[0]), float(s[1])

    def limits(self) -> dict[str, Any]:
        """The lower store's brim as an output level (what the measurement piles up at)."""
        return {"lower": None, "upper": _finite(self.params["ceiling"]), "where": "state"}

    def to_dict(self) -> dict[str, Any]:
        d = {"format": FORMAT, "version": VERSION, "kind": "siso", "structure": self.structure,
             "fs_hz": self.fs_hz, "substeps": self.substeps,
             "params": {k: _finite(v) for k, v in self.params.items()},
             "provenance": self.provenance, "metrics": self.metrics}
        return {**d, "saturation": self.limits()} if self.limited else d

    def copy(self) -> StoreChainModel:
        """The same model (parameters, substeps), a zero state."""
        return StoreChainModel(self.params, self.fs_hz, self.substeps, self.provenance, self.metrics)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StoreChainModel:
        """From its file form, the brims its own parameters (:func:`~rtlift.model.siso_file.model_from_dict`; KeyError,
        TypeError or ValueError if wrong)."""
        return cls(d["params"], float(d["fs_hz"]), int(d.get("substeps", 2)), d.get("provenance"), d.get("metrics"))


class SaturatedModel:
    """A hard limit on a model's output (``saturation``, where ``output``): a sensor or a stage
    that clips (Cascaded Tanks: the level sensor reads 10 V while the tank overflows):

        y(k) = min(max(M(u)(k), lower), upper)

    M any single-input model here (its ``structure`` is the model's); ``lower``/``upper`` may
    be infinite (no limit on that side). State and file form are M's, plus
    ``"saturation": {"lower", "upper", "where": "output"}`` (infinite limits as ``null``).
    """

    where = "output"

    def __init__(self, inner: SisoModel | FeedbackModel, lower: float, upper: float) -> None:
        lower, upper = float(lower), float(upper)
        if np.isnan(lower) or np.isnan(upper) or not lower < upper:
            raise ValueError(f"saturation needs lower < upper, got {lower}, {upper}")
        self.inner, self.lower, self.upper = inner, lower, upper

    structure = property(lambda self: self.inner.structure)
    fs_hz = property(lambda self: self.inner.fs_hz)
    state_size = property(lambda self: self.inner.state_size)

    provenance = property(lambda self: self.inner.provenance,
                          lambda self, value: setattr(self.inner, "provenance", value))
    metrics = property(lambda self: self.inner.metrics, lambda self, value: setattr(self.inner, "metrics", value))

    def step(self, u: float) -> float:
        return min(max(self.inner.step(u), self.lower), self.upper)

    def simulate(self, u: np.ndarray) -> np.ndarray:
        return np.clip(self.inner.simulate(u), self.lower, self.upper)

    def reset(self) -> None:
        self.inner.reset()

    def get_state(self) -> np.ndarray:
        return self.inner.get_state()

    def set_state(self, state: np.ndarray) -> None:
        self.inner.set_state(state)

    def limits(self) -> dict[str, Any]:
        return {"lower": _finite(self.lower), "upper": _finite(self.upper), "where": self.where}

    def to_dict(self) -> dict[str, Any]:
        return {**self.inner.to_dict(), "saturation": self.limits()}

    def copy(self) -> SaturatedModel:
        """The same limits around a copy of the inner model."""
        return SaturatedModel(self.inner.copy(), self.lower, self.upper)


SISO_MODELS = (SisoModel, FeedbackModel, StoreChainModel, SaturatedModel)
"""The single-input model classes (``isinstance(model, SISO_MODELS)``: a generic model)."""
MODEL_CLASSES: dict[str, Any] = {s.name: next((c for c in (FeedbackModel, StoreChainModel) if c.structure == s.name),
                                               SisoModel) for s in MODEL_STRUCTURES}
"""Each structure's model class, as the registry names it (:data:`rtlift.core.registry.MODEL_STRUCTURES`):
what :func:`~rtlift.model.siso_file.model_from_dict` builds a file of that ``structure`` with (its ``from_dict``)."""

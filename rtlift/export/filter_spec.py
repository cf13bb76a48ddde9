"""What an exported observer runs, read off the Python observer: the model's packed parameters
and state (:mod:`rtlift.blocks.compiled`, :mod:`rtlift.blocks.compiled_interaction`) and the
filter's constant matrices (:class:`~rtlift.observer.layout.StateLayout`), full or steady gain.

``--gain full`` is the observer of :mod:`rtlift.observer` as it is. ``--gain steady`` fixes the
gain at export: the states whose measurement row is set per sample by the burst (the ripple
coefficients r and the gain error δ: their row is zero in any fixed H, so no steady state exists
for them) are left out, and K, S come from the discrete algebraic Riccati equation

    P = F P Fᵀ − F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q,   S = H P Hᵀ + R,   K = P Hᵀ / S

at the nominal row H = [g₀ C, 1, h_s, e₁ᵀ], g₀ the Wiener gain at the operating point: N(Cμ_ref)
(paper form) or f′(y₀) at y₀ = C (I − A)⁻¹ B Cμ_ref (textbook form), Cμ_ref the table's largest
Cμ_env (the model's own). The step then predicts ξ⁻ = F ξ + G u and updates ξ = ξ⁻ + K ν with
the row of the sample for ẑ⁻ (as the full filter), without a covariance. A fixed gain that
lets the error grow, |eig((I − K H_g) F)| ≥ 1, for a gain g the Wiener part can take (the
paper's N over its grid, f′ on each segment of f, times the hysteresis factor's extremes) is
refused: its module would diverge there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from rtlift.core.errors import UserError
from rtlift.model.hybrid import HybridModel
from rtlift.observer import Observer, ObserverConfig
from rtlift.observer import compiled as cs


class ExportError(UserError):
    """A model or an option the C export cannot honour (one line, exit 2)."""


@dataclass(frozen=True)
class FilterSpec:
    """The filter an export runs: sizes, indices and constant matrices (dense ``F``; the
    generator writes its non-zeros). ``P0`` is None and ``K``, ``S`` are set for the steady gain."""

    dim_x: int
    n_wiener: int
    bias: int
    gain_h: int
    ripple_start: int
    harmonics: int
    powers: int
    max_period: int
    F: np.ndarray
    G: np.ndarray
    h_fixed: np.ndarray
    h_lift: np.ndarray
    Q: np.ndarray
    P0: np.ndarray | None
    K: np.ndarray | None
    S: float
    R: float
    gate: float
    max_rejections: int
    cmu_ref: float

    @property
    def full(self) -> bool:
        return self.K is None


def bound_observer(model: HybridModel, config: ObserverConfig | None = None) -> Observer:
    """The observer of ``model`` (its stored Q and R unless ``config``), refused with one line
    naming what has no compiled step (the C module is that step's translation)."""
    obs = Observer.from_model(model) if config is None else Observer(model, config)
    if any(st.name == "onset_hold" for st in model.input_stages):      # compiled, not translated (issue 47)
        raise ExportError("cannot export to C: the input stage 'onset_hold' has no C translation")
    if not obs.compiled:
        raise ExportError(f"cannot export to C: {_uncompiled_part(obs.model)}")
    return obs


def _uncompiled_part(model: HybridModel) -> str:
    """What of ``model`` the compiled step does not take, named."""
    for st in model.output_stages:
        if not type(st).compiled_form:
            return f"the output stage '{st.name}' has no compiled step"
    if model.wiener.kernel_arrays() is None:
        return f"the Wiener nonlinearity {type(model.wiener.nonlinearity).__name__} has no compiled step"
    names = [st.name for st in model.input_stages]
    return (f"the input stages {names} have no compiled step (it takes at most one 'delay', then at most "
            f"one 'actuator_fade', then the interaction structure's 'delivered_envelope')")


MODEL_ARGUMENTS = {
    False: ("mpar", "d_cmu", "d_env", "d_pos", "fade", "sstate", "buf", "pos", "z", "x"),
    True: ("mpar", "d_cmu", "d_env", "d_pos", "fade", "sstate", "m_in", "buf", "pos", "z", "m_conv", "x"),
}
"""The compiled model step's arguments after Cμ and Cμ_env, by name: the paper's structure
(:func:`~rtlift.blocks.compiled.hybrid_sample`) and the interaction structure (True)."""
FILTER_ARGUMENTS = ("ipar", "fpar", "Q", "xi", "P", "H", "T", "work", "tab", "s")


def kernel_arrays(obs: Observer) -> tuple[bool, dict[str, np.ndarray]]:
    """(interaction structure?, the compiled observer step's arguments by name): the model's
    packed parameters with the observer's output flags, the model's and the filter's state
    arrays, as :class:`Observer` binds them (the arrays themselves, not copies)."""
    fn, args, _ = obs._kernel      # the step the Python observer runs: the one to translate
    interaction = fn is not cs.observer_step
    return interaction, dict(zip(MODEL_ARGUMENTS[interaction] + FILTER_ARGUMENTS, args, strict=True))


def filter_spec(obs: Observer, gain: str = "full") -> FilterSpec:
    """The filter of ``obs`` (``gain`` "full") or its steady-gain form ("steady", module docstring)."""
    lay, cfg = obs.layout, obs.config
    common = dict(R=cfg.R, gate=obs.gate, max_rejections=cfg.max_rejections, cmu_ref=lay.cmu_ref)
    Q = obs.kf.Q
    if gain == "full":
        return FilterSpec(lay.dim_x, lay.n_wiener, lay.bias, lay.gain_h, lay.ripple_start, lay.harmonics,
                          lay.powers, lay.max_period, lay.F, lay.G, lay.h_fixed, lay.h_lift, Q, lay.P0(cfg),
                          None, 0.0, **common)
    if gain != "steady":
        raise ExportError(f"--gain {gain}: must be 'steady' or 'full'")
    drop = set(range(lay.ripple_start, lay.dim_x)) | ({lay.gain_h} if lay.gain_h >= 0 else set())
    keep = np.array([i for i in range(lay.dim_x) if i not in drop])
    F, G, Qk = lay.F[np.ix_(keep, keep)], lay.G[keep], Q[np.ix_(keep, keep)]
    h = lay.h_fixed[keep].copy()
    g0 = nominal_gain(obs.model, lay.cmu_ref)
    h[:lay.n_wiener] = g0 * lay.C
    try:
        P = solve_discrete_are(F.T, h.reshape(-1, 1), Qk, np.array([[cfg.R]]))
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ExportError(f"--gain steady: no steady-state Kalman gain for this model ({exc}); "
                          "use --gain full") from None
    S = float(h @ P @ h + cfg.R)
    K = P @ h / S
    if not (np.all(np.isfinite(K)) and S > 0):
        raise ExportError("--gain steady: the Riccati solution is not finite; use --gain full")
    radius, g = steady_radius(obs.model, F, K, h, lay.n_wiener, lay.C)
    if radius >= 1.0:
        raise ExportError(f"--gain steady: the fixed gain diverges where the Wiener gain is {g:.4g} (spectral "
                          f"radius {radius:.3g} of (I - K H) F; the gain was fixed at {g0:.4g}); "
                          "use --gain full")
    n = len(keep)
    return FilterSpec(n, lay.n_wiener, lay.bias, -1, n, 0, 0, lay.max_period, F, G, lay.h_fixed[keep],
                      lay.h_lift[keep], Qk, None, K, S, **common)


def wiener_gain_range(model: HybridModel) -> np.ndarray:
    """Every gain g(k) the measurement row's Wiener part can take, sampled: N over its grid
    (piecewise linear: between its values) or f′ on each segment of f, times the hysteresis
    factor's extremes g_h and g_h (1 + m) (h(k) ∈ [0, 1])."""
    nl = model.wiener.nonlinearity
    if hasattr(nl, "gain_at"):
        values = np.asarray(nl.gain, float)
        gains = np.union1d(values, np.linspace(values.min(), values.max(), 65))
    else:
        gains = np.diff(nl.f) / np.diff(nl.y)
    if hasattr(nl, "memory_arrays"):
        m, g = nl.memory_arrays()[0][:2]
        gains = np.concatenate([gains * g, gains * g * (1.0 + m)])
    return gains


def steady_radius(model: HybridModel, F: np.ndarray, K: np.ndarray, h: np.ndarray, n: int,
                  C: np.ndarray) -> tuple[float, float]:
    """(the largest spectral radius of the steady filter's error recursion e(k) = (I − K H_g) F e(k−1)
    over the gains g of :func:`wiener_gain_range`, H_g the nominal row with g C; that g)."""
    eye = np.eye(F.shape[0])
    worst = (0.0, float("nan"))
    for g in wiener_gain_range(model):
        row = h.copy()
        row[:n] = g * C
        r = float(np.max(np.abs(np.linalg.eigvals((eye - np.outer(K, row)) @ F))))
        worst = max(worst, (r, float(g)))
    return worst


def nominal_gain(model: HybridModel, cmu_ref: float) -> float:
    """g₀ of the steady gain's row (module docstring): N(Cμ_ref), or f′(C (I − A)⁻¹ B Cμ_ref)."""
    w = model.wiener
    nl = w.nonlinearity
    if hasattr(nl, "gain_at"):
        return float(nl.gain_at(cmu_ref))
    y0 = float(w.C @ np.linalg.solve(np.eye(w.A.shape[0]) - w.A, w.B)) * cmu_ref
    return float(nl.slope_at(y0))

"""Kalman observer of the lift increment ΔCL around the hybrid model (An, Williams & Hemati,
eq. 11), sample by sample at 400 Hz. Names as in Simon, *Optimal State Estimation* (F, G, H,
Q, R, P, K, ν, S) and Bar-Shalom et al. (NIS, χ² gate); the model's as in the paper (A, B, C,
N, φ, Cμ, ΔCL).

Modules: :mod:`~rtlift.observer.config` (:class:`ObserverConfig`, the flags),
:mod:`~rtlift.observer.layout` (:class:`StateLayout`: the state vector and its constant
matrices; :class:`BurstPhase`; :class:`StateBlock`), :mod:`~rtlift.observer.filter`
(:class:`Observer`, :class:`Estimate`), :mod:`~rtlift.observer.compiled` (the numba step),
:mod:`~rtlift.observer.tuning` (:func:`fit_noise`, :func:`tune_observer`).

State (dimension ``dim_x = n + 1 + Σ n_s + p + [1] + n_r``), in this order::

    ξ(k) = [ x(k) ; b(k) ; s(k) ; e(k) ; δ(k) ; r(k) ]

- ``x`` the n states of the Wiener LTI, in the paper's timing (eqs. 4–5);
- ``b`` a random-walk bias (sensor zero drift and slow model error);
- ``s`` the states accepted effects bring (:data:`~rtlift.observer.layout.OBSERVER_FORMS`: the
  rotating oscillators of a ``periodic_disturbance``, 2 per line), each a :class:`StateBlock`;
- ``e`` the coloured part of the measurement noise, AR(p) in companion form
  (``noise_ar`` = a₁ … a_p; absent when p = 0);
- ``δ`` a random-walk relative gain error of ΔCL_H (present when ``q_gain_h`` > 0);
- ``r`` the burst-synchronous ripple coefficients, ``n_r = 2 H P_r`` of them
  (``ripple_harmonics`` H, ``ripple_powers`` P_r; none for H = 0).

State equation (predict with the input at time k, then update with the measurement at k)::

    ξ(k) = F ξ(k−1) + G u(k) + w(k),   u(k) = Cμ_env(k),   w ~ N(0, Q)
    F = diag(A, 1, F_s, F_e, 1, I_{n_r}),   G = [B; 0; 0; 0; 0; 0]
    F_e = [a₁ … a_p ; I_{p−1} 0]   (e(k) = Σ a_i e(k−i) + w_e(k))
    Q = diag(q_x v vᵀ, q_bias, Q_s, q_noise e₁e₁ᵀ, q_gain_h, q_ripple I_{n_r}),   v = B / |C B|
    P(0) = diag(0, p0_bias, P_s, q_noise Σ_e, 0, p0_ripple I_{n_r})   (Σ_e: e's stationary covariance)

(``q_x`` is the variance per sample of a disturbance on y = C x, ``q_bias`` that of the bias
step, ``q_ripple`` that of a ripple coefficient's step, in ΔCL²/Cμ².)

Measurement (ΔCL from the balance), with a time-varying row::

    z(k) = ΔCL_H(k) + d(k) + c(k) + H(k) ξ(k) + v(k),   v ~ N(0, R)
    H(k) = [ g(k) C , 1 , h_s , e₁ᵀ , ΔCL_H(k) , r-row(k) ]

- ``ΔCL_H(k) = HF(φ Σ h(j) Cμ(k−j))`` is computed by the model's own blocks and enters as a
  known input; ``d(k)`` the corrections of the model's output stages that have no states here
  (exact for additive signals, a unit-slope linearisation for filters); input stages map
  (Cμ, Cμ_env) as in the model;
- paper form N(Cμ_env)·y: ``g(k) = N(Cμ_env(k))`` and ``c = 0`` (linear in ξ);
  textbook form f(y): linearised at the prediction ``ŷ⁻ = C x⁻`` (an extended Kalman filter),
  ``g(k) = f′(ŷ⁻)``, ``c(k) = f(ŷ⁻) − g(k) ŷ⁻``;
- ``r-row(k) = [Cμ_env(k) (Cμ_env(k)/Cμ_ref)^{p−1} · [cos(2π h φ(k)/P(k)), sin(2π h φ(k)/P(k))]_{h=1…H}]_{p=1…P_r}``
  with φ(k) the samples since the last burst onset and P(k) the interval between the last two
  (:class:`BurstPhase`); the row is zero while the phase is undefined (before two onsets, an
  interval longer than one burst response or ≤ 2H, and once φ ≥ P).

Update (scalar innovation, Joseph form)::

    ν = z − ẑ⁻,   S = H P⁻ Hᵀ + R,   K = P⁻ Hᵀ / S,   NIS = ν² / S
    ξ = ξ⁻ + K ν,   P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ  =  P⁻ − w wᵀ,  w = P⁻Hᵀ/√S

(the last equality holds for the optimal gain; the downdate is what runs: exactly symmetric,
positive definite for R > 0; the tests check it against filterpy's predict + update to 1e-12).

χ² gating: a sample with NIS above the ``gate_probability`` quantile of χ²₁ is rejected
(predict only, counted). Each such outlier adds 1 to a count, each sample inside the gate takes
:data:`GATE_LEAK` off it; when the count reaches ``max_rejections`` the next outlier is
accepted (:data:`FLAG_GATE_RELEASED`) and the gate stays open until the count has leaked back
to 0, so a real change the model misses is not locked out while isolated outliers are. A
missing or flagged sample (``dcl`` None or not finite) is predict only. NIS of the accepted
updates is tracked as a consistency monitor: running mean (≈ 1 when Q and R are right) and the
fraction inside the central 95 % band of χ²₁.

Estimate: ``ΔĈL(k) = ΔCL_H(k) + d(k) + nl(Cμ_env(k), C x(k)) + b(k) + h_lift s(k) + δ(k) ΔCL_H(k)
+ r-row(k) r(k)`` (the effect states that are part of the lift; pickups and the coloured noise
are not). ``est.model_dcl`` is the open-loop hybrid model (what ``model.step`` gives).

Q and R come from data (:func:`tune_observer`) and live in the model file's ``observer``
section; :meth:`Observer.from_model` reads them.

Hot path: :meth:`Observer.step` does no I/O, no logging and allocates no arrays; it is one
compiled call (:mod:`rtlift.observer.compiled`) when the model's step is compiled, and
:meth:`Observer.reference_step` (numpy and level-1/2 BLAS on the same arrays) otherwise.
"""

from rtlift.observer.config import (
    CONFIG_VERSION,
    FLAG_BAD_INPUT,
    FLAG_GATE_RELEASED,
    FLAG_MISSING,
    FLAG_REJECTED,
    GATE_LEAK,
    MAX_HARMONICS,
    NIS_BAND,
    ObserverConfig,
    ObserverError,
    chi2_1_quantile,
)
from rtlift.observer.filter import Estimate, Observer
from rtlift.observer.layout import OBSERVER_FORMS, BurstPhase, StateBlock, StateLayout
from rtlift.observer.tuning import actuator_off_noise, fit_noise, tune_observer

__all__ = ["CONFIG_VERSION", "FLAG_BAD_INPUT", "FLAG_GATE_RELEASED", "FLAG_MISSING", "FLAG_REJECTED",
           "GATE_LEAK", "MAX_HARMONICS", "NIS_BAND", "OBSERVER_FORMS", "BurstPhase", "Estimate", "Observer",
           "ObserverConfig", "ObserverError", "StateBlock", "StateLayout", "actuator_off_noise",
           "chi2_1_quantile", "fit_noise", "tune_observer"]

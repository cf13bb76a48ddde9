"""Systems of the kinds the product owner will run rtlift on, simulated from their published
descriptions (issue 48: no network here, so no measured record of them): development cases for
``tests/test_sysid_simulated.py`` and ``benchmarks/realdata.py``. Generators only, never data.

- :func:`ced_like` — the **coupled electric drives** kind (Wigren & Schoukens 2017, nonlinearbenchmark.org
  "CED"): two motors drive a pulley through a flexible belt held by a spring (a lightly damped mode);
  the belt speed is read by a pulse counter blind to the direction, so the output is |speed|, then a
  sensor low-pass. Two experiments of 500 samples at 50 Hz (low and high input amplitude), the first
  400 of each for estimation, the last 100 the test (scored by free run, the estimation input as
  the state's history). Simulated as a Wiener–Hammerstein system

      x = G₁(s) u,  G₁ = k α ω₀² / ((s + α)(s² + 2ζω₀ s + ω₀²)),  v = |x|,  y = v / (τ s + 1) + e,

  α = 3 rad/s, ω₀ = 2π·1.2 rad/s, ζ = 0.1, k = 1.5, τ = 0.05 s, e white with σ = 0.03, u uniform on
  ±a (a = 1 and 2) held for 5 samples. The values are ours (the description gives the shape, not
  these numbers).
- :func:`emps_like` — the **electro-mechanical positioning system** kind (Janot, Gautier & Brunot
  2019, "EMPS"): a prismatic joint, force τ in, position q out (a pure integrator with friction),

      M q̈ = τ − F_v q̇ − F_c sign(q̇) − c,

  M = 95.1 kg, F_v = 203.5 N s/m, F_c = 20.4 N, c = −3.16 N (the orders of the published reference
  model), run in closed loop (a position-velocity cascade, as the real records were taken) along
  smoothed point-to-point moves in [0, 0.2] m, sampled at 1 kHz; sign(q̇) smoothed as tanh(q̇/10⁻⁴).
  The estimation record and a test record of other moves ("pulses"), each 20 s; the force is the
  model's input and is measured with noise σ = 0.5 N, the position with σ = 2·10⁻⁶ m.
- :func:`bouc_wen` — the **Bouc–Wen** hysteretic benchmark (Noël & Schoukens 2016, nonlinear
  benchmark workshop), from its specification:

      m_L ÿ + c_L ẏ + k_L y + z = u,   ż = α ẏ − β (γ |ẏ| |z|^(ν−1) z + δ ẏ |z|^ν),

  m_L = 2 kg, c_L = 10 N s/m, k_L = 5·10⁴ N/m, α = 5·10⁴ N/m, β = 10³ m⁻¹, γ = 0.8, δ = −1.1,
  ν = 1, n = 1; sampled at 750 Hz, integrated by classical Runge–Kutta at 20 steps per sample with
  the input held (the specification uses Newmark integration at a fine step); random-phase
  multisines 5–150 Hz of 50 N RMS, 8192 samples a period (estimation: 5 periods, the first one a
  transient dropped by the protocol's unscored start; test: 1 further period of another
  realisation), and a sine-sweep test; output noise σ = 8·10⁻³ mm. The parameter values are the
  specification's as we hold them; we had no copy of the PDF in this session to check the
  excitation and noise details against.

What these simulations are NOT: measured data. No drift, no sensor quirk beyond those named, no
nonstationarity, no actuator nonlinearity of the real rigs; the CED's true model is exactly a
Wiener–Hammerstein system with |·| (the real one is only described so), the EMPS's friction is the
smooth Coulomb–viscous reference model (no Stribeck effect, no stiction, no position-dependent
cogging), and the closed loop's controller is ours. Numbers measured on them say what rtlift does
on systems of those kinds, not what it will score on the published records.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import signal

Runs = list[tuple[str, np.ndarray, np.ndarray]]


def _c2d(num: list[float], den: list[float], fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of num(s)/den(s) at ``fs`` (Hz)."""
    b, a, _ = signal.cont2discrete((num, den), 1.0 / fs, method="zoh")
    return np.atleast_1d(np.squeeze(b)), np.atleast_1d(np.squeeze(a))


CED_FS = 50.0
CED_ESTIMATION = 400


def ced_like(seed: int, noise: float = 0.03) -> tuple[float, Runs, Runs, Runs]:
    """(fs, estimation runs, full runs, noise-free full runs): two experiments of 500 samples (low,
    high amplitude); estimation the first :data:`CED_ESTIMATION` of each, the test the rest."""
    rng = np.random.default_rng(seed)
    al, w0, z, k, tau = 3.0, 2 * np.pi * 1.2, 0.1, 1.5, 0.05
    b1, a1 = _c2d([k * al * w0**2], np.polymul([1.0, al], [1.0, 2 * z * w0, w0**2]), CED_FS)
    b2, a2 = _c2d([1.0], [tau, 1.0], CED_FS)
    est, full, clean = [], [], []
    for name, amp in (("low", 1.0), ("high", 2.0)):
        u = np.repeat(rng.uniform(-amp, amp, 100), 5)[:500]
        y0 = signal.lfilter(b2, a2, np.abs(signal.lfilter(b1, a1, u)))
        y = y0 + noise * rng.standard_normal(u.size)
        est.append((name, u[:CED_ESTIMATION], y[:CED_ESTIMATION]))
        full.append((name, u, y))
        clean.append((name, u, y0))
    return CED_FS, est, full, clean


EMPS_FS = 1000.0
EMPS = dict(mass=95.1, viscous=203.5, coulomb=20.4, offset=-3.16)


def _emps_reference(rng: np.random.Generator, n: int, kind: str) -> np.ndarray:
    """Smoothed point-to-point moves in [0, 0.2] m: dwell-and-move targets (``estimation``) or
    short excursions from a rest position and back (``pulses``), through a 2 Hz second-order filter."""
    targets, k = np.empty(n), 0
    rest = 0.1
    while k < n:
        hold = int(rng.integers(600, 2000))
        if kind == "pulses":
            level = rest + rng.choice([-1, 1]) * rng.uniform(0.02, 0.09)
            targets[k:k + hold // 3] = level
            targets[k + hold // 3:k + hold] = rest
        else:
            targets[k:k + hold] = rng.uniform(0.0, 0.2)
        k += hold
    b, a = signal.butter(2, 2.0, fs=EMPS_FS)
    return signal.lfilter(b, a, targets - targets[0]) + targets[0]


def emps_like(seed: int, seconds: float = 20.0) -> tuple[float, Runs, Runs]:
    """(fs, [estimation run], [test run "pulses"]): force (N) in, position (m) out, measured with
    noise; each run starts at rest at its reference's first position (subtracted: q(0) = 0)."""
    rng = np.random.default_rng(seed)
    m, fv, fc, c = EMPS["mass"], EMPS["viscous"], EMPS["coulomb"], EMPS["offset"]
    n = int(seconds * EMPS_FS)
    sub = 10
    h = 1.0 / (EMPS_FS * sub)
    kp, kv, ki = 20.0, 3000.0, 20000.0     # position (1/s), velocity (N s/m), velocity integral (N/m)
    runs = []
    for kind in ("estimation", "pulses"):
        ref = _emps_reference(rng, n, kind)
        ref = ref - ref[0]
        q = v = integ = 0.0
        u, y = np.empty(n), np.empty(n)
        for i in range(n):
            e = kp * (ref[i] - q) - v
            tau = kv * e + ki * integ
            integ += e / EMPS_FS
            y[i] = q
            u[i] = tau
            for _ in range(sub):     # semi-implicit Euler at 10 kHz, the force held
                a = (tau - fv * v - fc * np.tanh(v / 1e-4) - c) / m
                v += h * a
                q += h * v
        runs.append((kind, u + 0.5 * rng.standard_normal(n), y + 2e-6 * rng.standard_normal(n)))
    return EMPS_FS, [runs[0]], [runs[1]]


BW_FS = 750.0
BW = dict(m=2.0, c=10.0, k=5e4, alpha=5e4, beta=1e3, gamma=0.8, delta=-1.1, nu=1.0)
BW_PERIOD = 8192


def _multisine(rng: np.random.Generator, periods: int, rms: float = 50.0) -> np.ndarray:
    """Random-phase multisine, every bin of 5–150 Hz at one amplitude, ``rms`` N, repeated."""
    f = np.fft.rfftfreq(BW_PERIOD, 1.0 / BW_FS)
    spec = np.zeros(f.size, complex)
    band = (f >= 5.0) & (f <= 150.0)
    spec[band] = np.exp(2j * np.pi * rng.uniform(size=int(band.sum())))
    one = np.fft.irfft(spec, BW_PERIOD)
    return np.tile(rms * one / np.sqrt(np.mean(one**2)), periods)


def _sweep(n: int, amplitude: float = 40.0) -> np.ndarray:
    """Sine sweep from 5 to 150 Hz over ``n`` samples, linear in frequency."""
    t = np.arange(n) / BW_FS
    return amplitude * signal.chirp(t, 5.0, t[-1], 150.0)


def bouc_wen_response(u: np.ndarray) -> np.ndarray:
    """Displacement y (m) of the Bouc–Wen system (module docstring) under force ``u`` (N), from
    rest; classical RK4 at 20 steps per sample, ``u`` held over the sample (compiled)."""
    p = BW
    out = np.empty(len(u))
    _bouc_wen_run(np.ascontiguousarray(u, dtype=float), out, 1.0 / (BW_FS * 20), p["m"], p["c"], p["k"],
                  p["alpha"], p["beta"], p["gamma"], p["delta"], p["nu"])
    return out


@numba.njit(cache=False)
def _bw_rate(y, v, z, force, m, c, k, al, be, ga, de, nu):   # pragma: no cover
    az = abs(z)
    return v, (force - c * v - k * y - z) / m, al * v - be * (ga * abs(v) * az ** (nu - 1) * z + de * v * az**nu)


@numba.njit(cache=False)
def _bouc_wen_run(u, out, h, m, c, k, al, be, ga, de, nu):   # pragma: no cover
    y = v = z = 0.0
    for i in range(u.size):
        out[i] = y
        f = u[i]
        for _ in range(20):
            a1, b1, c1 = _bw_rate(y, v, z, f, m, c, k, al, be, ga, de, nu)
            a2, b2, c2 = _bw_rate(y + h / 2 * a1, v + h / 2 * b1, z + h / 2 * c1, f, m, c, k, al, be, ga, de, nu)
            a3, b3, c3 = _bw_rate(y + h / 2 * a2, v + h / 2 * b2, z + h / 2 * c2, f, m, c, k, al, be, ga, de, nu)
            a4, b4, c4 = _bw_rate(y + h * a3, v + h * b3, z + h * c3, f, m, c, k, al, be, ga, de, nu)
            y += h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            v += h / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
            z += h / 6 * (c1 + 2 * c2 + 2 * c3 + c4)


def bouc_wen(seed: int, periods: int = 5, noise: float = 8e-6) -> tuple[float, Runs, Runs]:
    """(fs, [estimation run], [test multisine, test sweep]): force (N) in, displacement (m) out.
    Each test record starts with one period of its own multisine (or sweep lead-in) so that the
    scored part is in steady state; the protocol leaves its first samples unscored too."""
    rng = np.random.default_rng(seed)
    u_est = _multisine(rng, periods)
    u_ms = _multisine(rng, 2)
    u_sw = _sweep(4 * BW_PERIOD)
    runs = []
    for name, u in (("estimation", u_est), ("test_multisine", u_ms), ("test_sweep", u_sw)):
        runs.append((name, u, bouc_wen_response(u) + noise * rng.standard_normal(u.size)))
    return BW_FS, runs[:1], runs[1:]

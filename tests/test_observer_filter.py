"""The Kalman observer's equations on small synthetic models (fast; no bench, no I/O)."""

from __future__ import annotations

import dataclasses
import math
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from rtlift.blocks.delay import Delay
from rtlift.blocks.periodic_disturbance import PeriodicDisturbance
from rtlift.blocks.stage_base import OutputStage
from rtlift.blocks.stages import STAGES
from rtlift.blocks.wiener import OutputHysteresis
from rtlift.effects.surgery import augment
from rtlift.observer import (
    FLAG_GATE_RELEASED,
    FLAG_MISSING,
    FLAG_REJECTED,
    NIS_BAND,
    BurstPhase,
    Observer,
    ObserverConfig,
    ObserverError,
    fit_noise,
)
from testkit.synthetic import burst_input, make_model

CFG = ObserverConfig(R=1.6e-5, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4)
FULL = ObserverConfig(R=8e-6, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, noise_ar=(1.82, -0.85), q_noise=7e-8,
                      q_gain_h=1e-5, ripple_harmonics=4, q_ripple=1e-8, p0_ripple=0.1)
"""Every kind of state: Wiener, bias, coloured noise (AR(2)), ΔCL_H gain, 8 ripple coefficients."""


def noisy_measurement(model, cmu, env, sigma, rng, offset=0.0):
    model.reset()
    truth = model.simulate(cmu, env).total + offset
    model.reset()
    return truth, truth + rng.normal(0.0, sigma, truth.size)


def noisy_case(rng, n, **model_kw):
    """(model, cmu, env, truth, z): a random model (:func:`testkit.synthetic.make_model` with
    ``model_kw``), ``n`` samples of burst input, its ΔCL and that measured with σ = 0.004 noise."""
    model = make_model(rng, **model_kw)
    cmu, env = burst_input(rng, n)
    truth, z = noisy_measurement(model, cmu, env, 0.004, rng)
    return model, cmu, env, truth, z


def stepped(obs, cmu, env, z, n):
    """``obs`` after its steps on the first ``n`` samples (returned)."""
    for k in range(n):
        obs.step(cmu[k], env[k], z[k])
    return obs


@pytest.mark.parametrize("path", ["compiled", "reference"])
@pytest.mark.parametrize(("output_form", "cfg"), [(False, CFG), (True, CFG), (False, FULL), (True, FULL)],
                         ids=["input_gain", "output_nonlinearity", "input_gain_all_states", "output_all_states"])
def test_step_is_filterpy_predict_then_joseph_update_with_the_time_varying_H(rng, output_form, cfg, path):
    """The compiled step and the in-place BLAS reference step each equal filterpy's predict +
    Joseph update on the same row H(k) = [N C, 1, h_noise, ΔCL_H(k), Cμ_env(k)·basis(φ(k))] to
    1e-12 relative, every sample."""
    model, cmu, env, _, z = noisy_case(rng, 600, output_form=output_form)
    cfg = dataclasses.replace(cfg, gate_probability=1.0)    # every sample updates: compare all of them
    obs = Observer(model, cfg)
    assert obs.compiled
    step = obs.step if path == "compiled" else obs.reference_step
    st = obs.layout
    ref_model = obs.model.with_stages()                # same parameters, fresh state
    phase = BurstPhase(cfg.ripple_harmonics, st.max_period)
    kf = KalmanFilter(dim_x=st.dim_x, dim_z=1, dim_u=1)
    kf.F, kf.B, kf.Q, kf.R = st.F, st.G.reshape(-1, 1), st.Q(cfg), np.array([[cfg.R]])
    kf.x, kf.P = np.zeros(st.dim_x), st.P0(cfg)
    nl, n = ref_model.wiener.nonlinearity, st.n_wiener
    worst = 0.0
    for k in range(cmu.size):
        _, high, _ = ref_model.step(cmu[k], env[k])
        kf.predict(u=np.array([env[k]]))
        H = st.h_fixed.copy()
        if output_form:
            y = float(st.C @ kf.x[:n])
            g = nl.slope_at(y)
            c = nl.step(env[k], y) - g * y
        else:
            g, c = nl.gain_at(env[k]), 0.0
        H[:n] = g * st.C
        if st.gain_h >= 0:
            H[st.gain_h] = high
        row = phase.step(cmu[k]) if cfg.ripple_harmonics else None
        if row is not None:
            H[st.ripple_start:] = env[k] * row
        kf.update(np.array([z[k] - high - c]), H=H.reshape(1, -1))
        est = step(cmu[k], env[k], z[k])
        assert est.flags == 0
        scale_x, scale_p = np.max(np.abs(kf.x)), np.max(np.abs(kf.P))
        np.testing.assert_allclose(obs.kf.x, kf.x, rtol=1e-12, atol=1e-12 * scale_x)
        np.testing.assert_allclose(obs.kf.P, kf.P, rtol=1e-12, atol=1e-12 * scale_p)
        worst = max(worst, np.max(np.abs(obs.kf.P - kf.P)) / scale_p)
    lift = kf.x[n] + (H[st.ripple_start:] @ kf.x[st.ripple_start:] if cfg.ripple_harmonics else 0.0) + \
        (high * kf.x[st.gain_h] if st.gain_h >= 0 else 0.0)
    assert est.dcl == pytest.approx(high + nl.step(env[-1], float(st.C @ kf.x[:n])) + lift, abs=1e-12)
    assert worst < 1e-12


def test_the_burst_phase_is_read_from_the_cmu_column():
    """Onsets every 50 samples (4 on), then a 400-sample pause (longer than the kernel) and a
    too-short interval: the row is defined exactly while φ < P for a known 2H < P ≤ max."""
    ph = BurstPhase(harmonics=3, max_period=300)
    cmu = np.zeros(1000)
    for start in (10, 60, 110, 510, 560, 564):
        cmu[start:start + 2] = 0.01
    rows = np.zeros((cmu.size, 6))
    for k, c in enumerate(cmu):
        row = ph.step(c)
        if row is not None:
            rows[k] = row
    defined = np.any(rows != 0, axis=1)
    assert not defined[:60].any()                   # one onset only: period unknown
    assert defined[60:160].all() and not defined[160:560].any()   # φ < 50 after the 2nd and 3rd
    assert not defined[564:].any()                  # 400 > max_period, then 4 ≤ 2H
    phi = 2 * np.pi * np.arange(50) / 50
    np.testing.assert_allclose(rows[60:110], np.column_stack(
        [np.cos(h * phi) for h in (1, 2, 3)] + [np.sin(h * phi) for h in (1, 2, 3)]), atol=1e-15)
    np.testing.assert_array_equal(rows[60:110], rows[110:160])


def test_ripple_states_remove_a_burst_locked_ripple_the_model_lacks(rng):
    """A ripple Cμ_env·(2 cos + 1.5 sin − 1 cos 3)(2πφ/50) of ≈ 0.02 that the convolution does
    not have: with H = 4 ripple states the estimate is 3× closer to the truth than without, and
    closer than the raw measurement."""
    model = make_model(rng, kernel_len=60)            # bursts every 50 samples: within one response
    cmu, env = burst_input(rng, 8000)
    truth = model.simulate(cmu, env).total
    model.reset()
    phi = 2 * np.pi * (np.arange(cmu.size) % 50) / 50
    truth = truth + env * (2.0 * np.cos(phi) + 1.5 * np.sin(phi) - 1.0 * np.cos(3 * phi))
    z = truth + rng.normal(0.0, 0.004, truth.size)
    base = dict(R=0.004**2, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4)
    rms = lambda e: float(np.sqrt(np.mean(e[2000:] ** 2)))  # noqa: E731
    e_plain = rms(Observer(model, ObserverConfig(**base)).run(cmu, env, z)["dcl"] - truth)
    obs = Observer(model, ObserverConfig(**base, ripple_harmonics=4, q_ripple=1e-6, p0_ripple=10.0))
    e_ripple = rms(obs.run(cmu, env, z)["dcl"] - truth)
    assert e_ripple < e_plain / 3                 # measured 0.0032 vs 0.0103
    assert e_ripple < 0.85 * 0.004                # closer than the raw measurement


def test_fit_noise_recovers_a_white_plus_ar2_noise(rng):
    """Buffeting-like noise: white σ 0.0025 plus an AR(2) resonance near 10 Hz (r = 0.93),
    in 3 segments of 800 samples as the tare seconds give."""
    a = (2 * 0.93 * np.cos(2 * np.pi * 10 / 400), -0.93**2)
    segs = []
    for _ in range(3):
        e = np.zeros(1000)
        w = rng.normal(0, 2.7e-4, 1000)
        for k in range(2, 1000):
            e[k] = a[0] * e[k - 1] + a[1] * e[k - 2] + w[k]
        segs.append(e[200:] + rng.normal(0, 0.0025, 800))
    fit = fit_noise(segs)
    assert math.sqrt(fit["R"]) == pytest.approx(0.0025, rel=0.1)
    np.testing.assert_allclose(fit["noise_ar"], a, atol=0.03)
    assert fit["q_noise"] == pytest.approx(2.7e-4**2, rel=0.5)
    white = fit_noise([rng.normal(0, 0.004, 800) for _ in range(3)])
    assert white["noise_ar"] == () and math.sqrt(white["R"]) == pytest.approx(0.004, rel=0.05)


def test_fit_noise_on_a_tare_that_drove_its_simplex_to_overflow():
    """Plant draw 125's 2-s tare (its campaign's random training record, the lift with the actuator
    off): the likelihood's simplex wandered to a pole angle whose logistic overflowed ``math.exp``,
    and ``rtlift identify`` ended in an internal error. It now fits, and the fit accounts for the
    segment's variance: white plus coloured within 20 % of the total."""
    z = np.load(Path(__file__).parent / "data" / "tare_noise_draw125.npy")
    fit = fit_noise([z])
    assert all(math.isfinite(v) for v in (fit["R"], fit["q_noise"], *fit["noise_ar"]))
    assert len(fit["noise_ar"]) == 2 and fit["R"] > 0
    assert fit["R"] + fit["coloured_std"] ** 2 == pytest.approx(fit["total"], rel=0.2)


def test_dense_outliers_open_the_gate_isolated_ones_stay_out(rng):
    """Outliers every 173rd sample are all rejected; a stretch where every other sample is out
    of the gate (a real change the model misses) piles up 1 − 1/4 per pair and opens it at the
    15th outlier (count 0.75 · 14 ≥ 10); it then stays open for the rest of the stretch."""
    model, cmu, env, _, z = noisy_case(rng, 3000)
    cfg = ObserverConfig(R=1.6e-5, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, max_rejections=10)
    isolated = z.copy()
    isolated[500::173] += 0.3
    out = Observer(model, cfg).run(cmu, env, isolated)
    assert np.all(out["flags"][500::173] == FLAG_REJECTED)
    dense = z.copy()
    dense[1000:1100:2] += 0.3
    obs = Observer(model, cfg)
    out = obs.run(cmu, env, dense)
    flags = out["flags"][1000:1100:2]
    assert np.all(flags[:14] == FLAG_REJECTED)
    assert np.all(flags[14:] == FLAG_GATE_RELEASED)
    assert np.sum(out["flags"][1000:1100] == FLAG_REJECTED) == 14


def test_a_missing_sample_is_predict_only_and_grows_the_covariance(rng):
    model, cmu, env, _, z = noisy_case(rng, 300)
    obs = stepped(Observer(model, CFG), cmu, env, z, 299)
    x_before, p_before = obs.kf.x.copy(), np.trace(obs.kf.P)
    est = obs.step(cmu[299], env[299], None)
    st = obs.layout
    np.testing.assert_allclose(obs.kf.x, st.F @ x_before + st.G * env[299], rtol=1e-12, atol=1e-15)
    assert np.trace(obs.kf.P) > p_before
    assert est.flags == FLAG_MISSING and math.isnan(est.innovation) and math.isnan(est.nis)
    assert obs.missing == 1 and obs.updates == 299


def test_an_outlier_is_gated_out_counted_and_leaves_the_estimate_on_the_prediction(rng):
    model, cmu, env, _, z = noisy_case(rng, 600)
    obs = stepped(Observer(model, CFG), cmu, env, z, 599)
    twin = stepped(Observer(model, CFG), cmu, env, z, 599)
    est = obs.step(cmu[599], env[599], z[599] + 0.5)        # a 125 σ spike
    missing = twin.step(cmu[599], env[599], None)
    assert est.flags == FLAG_REJECTED and obs.rejected == 1
    assert est.nis > obs.gate
    assert est.dcl == missing.dcl                            # exactly the prediction
    np.testing.assert_array_equal(obs.kf.P, twin.kf.P)


def test_a_persistent_step_is_accepted_after_max_rejections(rng):
    model = make_model(rng)
    cfg = ObserverConfig(R=1.6e-5, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4, max_rejections=5)
    obs = Observer(model, cfg)
    flags = [obs.step(0.0, 0.0, 0.3).flags for _ in range(7)]
    assert flags[:5] == [FLAG_REJECTED] * 5
    assert flags[5] == FLAG_GATE_RELEASED
    assert obs.rejected == 5 and obs.updates == 2


@pytest.mark.parametrize("cfg", [CFG, FULL], ids=["plain", "all_states"])
def test_get_state_set_state_resumes_bit_for_bit(rng, cfg):
    model, cmu, env, _, z = noisy_case(rng, 500)
    obs = stepped(Observer(model, cfg), cmu, env, z, 250)
    saved = obs.get_state()
    first = [obs.step(cmu[k], env[k], z[k]).as_tuple() for k in range(250, 500)]
    other = Observer(model, cfg)
    other.set_state(saved)
    second = [other.step(cmu[k], env[k], z[k]).as_tuple() for k in range(250, 500)]
    assert first == second


def test_from_model_without_observer_settings_says_what_to_do(rng):
    with pytest.raises(ObserverError, match="no observer settings.*tune_observer"):
        Observer.from_model(make_model(rng))


def test_from_model_reads_the_stored_settings(rng):
    model = make_model(rng)
    model.observer_config = CFG.to_dict()
    obs = Observer.from_model(model)
    assert obs.config.R == CFG.R and obs.kf.R[0, 0] == CFG.R
    np.testing.assert_array_equal(obs.kf.Q, obs.layout.Q(CFG))


def test_the_bias_state_tracks_a_sensor_offset_the_model_lacks(rng):
    model = make_model(rng)
    cmu, env = burst_input(rng, 4000)
    truth, z = noisy_measurement(model, cmu, env, 0.004, rng, offset=0.02)
    obs = Observer(model, ObserverConfig(R=1.6e-5, q_x=0.0, q_bias=1e-8, p0_bias=1e-3))
    out = obs.run(cmu, env, z)
    assert np.mean(out["dcl"][-1000:] - truth[-1000:]) == pytest.approx(0.0, abs=0.001)
    assert np.mean(out["model_dcl"][-1000:] - truth[-1000:]) == pytest.approx(-0.02, abs=1e-9)


def test_nis_is_consistent_when_the_model_is_right(rng):
    """With the true model and the true R, NIS is χ²₁: mean ≈ 1, 95 % inside the band."""
    model, cmu, env, _, z = noisy_case(rng, 8000)
    obs = Observer(model, ObserverConfig(R=0.004**2, q_x=0.0, q_bias=1e-12, p0_bias=1e-8))
    obs.run(cmu, env, z)
    assert obs.nis_mean == pytest.approx(1.0, abs=0.06)
    assert obs.nis_band_fraction == pytest.approx(0.95, abs=0.01)
    assert NIS_BAND[0] < 0.01 and 5.0 < NIS_BAND[1] < 5.05


@pytest.mark.parametrize("path", ["compiled", "reference"])
@pytest.mark.parametrize("cfg", [CFG, FULL], ids=["plain", "all_states"])
def test_a_step_allocates_nothing_that_stays(rng, cfg, path):
    """tracemalloc: after warm-up, steps retain only the few floats of the reused Estimate
    (not growing with the number of steps) and their transient peak is a few hundred bytes
    (the reference step builds a burst period's basis table when the period changes)."""
    model, cmu, env, _, z = noisy_case(rng, 5000, kernel_len=300)
    cmu, env, z = cmu.tolist(), env.tolist(), z.tolist()
    obs = Observer(model, cfg)
    step = obs.step if path == "compiled" else obs.reference_step
    first = step(cmu[0], env[0], z[0])
    for k in range(1, 1000):
        step(cmu[k], env[k], z[k])
    retained = []
    tracemalloc.start()
    for stop in (2000, 5000):
        tracemalloc.reset_peak()
        start = len(retained) and 2000 or 1000
        for k in range(start, stop):
            est = step(cmu[k], env[k], z[k] if k % 7 else None)
        current, peak = tracemalloc.get_traced_memory()
        retained.append(current)
    tracemalloc.stop()
    assert est is first
    period, rows = obs.phase._period_rows     # the reference step's basis table, if any
    table = rows[0].base.nbytes + sum(sys.getsizeof(r) for r in rows) + sys.getsizeof(rows) if rows else 0
    assert max(retained) <= 512 + 1.2 * table    # a leak of one object per step would be > 50 kB
    assert peak - current <= 2048 + 4 * table     # + building the basis table when the burst period changes


class _Pickup(OutputStage, register=False):
    """A narrow-band pickup added to the measured lift (what an accepted
    ``periodic_disturbance`` effect puts in the model)."""

    name = "periodic_disturbance"
    state_size = 1

    def __init__(self, frequency_hz: float, amplitude: float, fs_hz: float) -> None:
        self.f, self.a, self.fs, self.k = frequency_hz, amplitude, fs_hz, 0

    @classmethod
    def from_params(cls, params, fs_hz):
        return cls(params["frequency_hz"], params["amplitude"], fs_hz)

    def params(self):
        return {"frequency_hz": self.f, "amplitude": self.a}

    def step(self, dcl):
        self.k += 1
        return dcl + self.a * math.sin(2 * math.pi * self.f * self.k / self.fs)

    def simulate(self, dcl):
        return np.array([self.step(v) for v in dcl])

    def get_state(self):
        return np.array([float(self.k)])

    def set_state(self, state):
        self.k = int(np.asarray(state)[0])


def test_an_accepted_periodic_disturbance_adds_oscillator_states_that_remove_the_pickup(rng, monkeypatch):
    monkeypatch.setitem(STAGES, "periodic_disturbance", _Pickup)
    model, cmu, env, truth, z = noisy_case(rng, 6000)
    t = np.arange(1, z.size + 1) / 400.0
    z = z + 0.01 * np.sin(2 * np.pi * 20.0 * t + 1.3)         # phase unknown to the model
    augmented = model.with_stages(output_stages=(_Pickup(20.0, 0.01, 400.0),))
    cfg = ObserverConfig(R=0.004**2, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4)
    plain = Observer(model, cfg)
    with_states = Observer(augmented, cfg)
    assert with_states.layout.dim_x == plain.layout.dim_x + 2
    e_plain = plain.run(cmu, env, z)["dcl"][2000:] - truth[2000:]
    e_aug = with_states.run(cmu, env, z)["dcl"][2000:] - truth[2000:]
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    assert rms(e_aug) < 0.5 * rms(e_plain)
    assert rms(e_aug) < 0.003


def test_a_pickup_with_harmonics_adds_two_oscillator_states_per_line_that_remove_it(rng):
    """What the diagnosis now accepts for mains: the fundamental and its harmonics as sampled."""
    model, cmu, env, truth, z = noisy_case(rng, 6000)
    t = np.arange(1, z.size + 1) / 400.0
    z = z + 0.01 * np.sin(2 * np.pi * 60.02 * t + 1.3) + 0.004 * np.sin(2 * np.pi * 99.9 * t - 0.4)
    pickup = PeriodicDisturbance(60.02, 0.01, 0.0, 400.0, [{"n": 5, "amplitude": 0.004}])   # 300.1 -> 99.9 Hz
    augmented = model.with_stages(output_stages=(pickup,))
    cfg = ObserverConfig(R=0.004**2, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4)
    plain, with_states = Observer(model, cfg), Observer(augmented, cfg)
    assert with_states.layout.dim_x == plain.layout.dim_x + 4
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    e_plain = plain.run(cmu, env, z)["dcl"][2000:] - truth[2000:]
    e_aug = with_states.run(cmu, env, z)["dcl"][2000:] - truth[2000:]
    assert rms(e_aug) < 0.5 * rms(e_plain)


def test_the_observer_runs_the_identified_structures_open_loop_exactly(rng):
    """Dead time (a delay input stage) and hysteresis on the textbook form: with no measurement the
    observer's model output is the model's own, sample for sample."""
    base = make_model(rng, output_form=True)
    nl = base.wiener.nonlinearity
    model = augment(base, input_stage=Delay(3 / 400.0, 400.0),
                    nonlinearity=OutputHysteresis(nl.y, nl.f, 0.2, 0.1, 400.0, 0.002, 0.9))
    cmu, env = burst_input(rng, 2000)
    cfg = ObserverConfig(R=0.004**2, q_x=1e-9, q_bias=1e-9, p0_bias=1e-4)
    out = Observer(model, cfg).run(cmu, env, np.full(cmu.size, np.nan))
    model.reset()
    np.testing.assert_allclose(out["model_dcl"], model.simulate(cmu, env).total, atol=1e-12)
    assert np.all(np.isfinite(out["dcl"]))

"""Single-burst kernel: onsets, phase average, noise-floor cut, φ (paper eq. 1)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from rtlift.core.rate import FS_HZ as FS
from rtlift.identify.kernel import burst_onsets, fit_kernel

CMU_REF = 0.0022


def response(n: int = 300) -> np.ndarray:
    """A single-burst-like impulse response per unit Cμ·sample: dip, then a slow bump."""
    t = np.arange(n) / FS
    return 20.0 * (np.exp(-t / 0.08) * (t / 0.08) - 0.3 * np.exp(-t / 0.01))


def burst_record(rng, noise: float, n_bursts: int = 20, spacing: int = 400):
    n = 200 + n_bursts * spacing
    cmu = np.zeros(n)
    onsets = 200 + spacing * np.arange(n_bursts)
    for o in onsets:
        cmu[o:o + 4] = CMU_REF
    dcl = signal.lfilter(response(), [1.0], cmu) + rng.normal(0, noise, n)
    return cmu, dcl, onsets


def test_burst_onsets_are_the_rising_edges(rng):
    cmu, _, onsets = burst_record(rng, 0.0)
    np.testing.assert_array_equal(burst_onsets(cmu), onsets)


def test_noise_free_bursts_give_a_kernel_whose_convolution_reproduces_the_response(rng):
    cmu, dcl, _ = burst_record(rng, 0.0)
    k = fit_kernel(cmu, dcl, FS, smooth=False)
    assert k.n_bursts == 19 or k.n_bursts == 20
    assert k.burst_samples == 4 and np.isclose(k.burst_cmu, CMU_REF)
    assert k.reproduction_nrmse < 0.2                  # 4-sample smear of a sharp dip
    # φ normalises the burst: φ Σ c_b ≈ 1
    assert abs(k.phi * 4 * CMU_REF - 1.0) < 0.1


def test_kernel_of_noisy_bursts_is_cut_where_it_sinks_into_the_noise(rng):
    cmu, dcl, _ = burst_record(rng, 0.01)
    k = fit_kernel(cmu, dcl, FS)
    true = signal.lfilter(response(), [1.0], np.r_[np.full(4, CMU_REF), np.zeros(396)])
    # cut where the true response sinks below the noise floor of the average
    floor = k.noise_floor
    assert 0.01 / np.sqrt(20) * 0.7 < floor < 0.01 / np.sqrt(19) * 1.3
    last_visible = np.flatnonzero(np.abs(true) > floor)[-1]
    assert abs(k.kernel.size - last_visible) < 0.1 * FS
    assert k.kernel[-1] == 0.0                            # tapered to zero
    # smoothing + cut beat the raw average against the truth
    m = k.kernel.size
    raw_err = np.sqrt(np.mean((k.raw - true[: k.raw.size]) ** 2))
    ker_err = np.sqrt(np.mean((np.r_[k.kernel, np.zeros(k.raw.size - m)]
                               - true[: k.raw.size]) ** 2))
    assert ker_err < 0.7 * raw_err


def modulated_train(rng, n: int = 8000, period: int = 51) -> np.ndarray:
    """Bursts every ``period`` samples whose amplitude follows a slow random envelope."""
    cmu = np.zeros(n)
    env = 0.011 + 0.009 * np.sin(2 * np.pi * np.arange(n) / 1600.0 + rng.uniform(0, 6))
    for o in range(10, n - 4, period):
        cmu[o:o + 4] = env[o]
    return cmu


def test_refinement_recovers_the_kernels_first_period_from_a_modulated_train(rng):
    """The single-burst average misses detail in the first period (here: a 31 Hz ripple it
    smoothed away); the training record's residual is exactly X δh plus noise: the refinement
    finds δh within the noise and is kept on held-out error."""
    from rtlift.identify.kernel import refine_kernel

    h_true = response(300)
    delta = np.zeros(300)
    delta[:51] = 0.8 * np.sin(2 * np.pi * 31.0 * np.arange(51) / FS) * np.hanning(51)
    h0 = h_true - delta                                   # what the single bursts gave
    cmu = modulated_train(rng)
    unit = signal.lfilter([1.0], [1.0], cmu)              # high branch of a unit kernel: here no filter
    resid = signal.lfilter(h_true, [1.0], cmu) - signal.lfilter(h0, [1.0], cmu)
    resid += rng.normal(0, 0.1 * resid.std(), cmu.size)
    n_est = int(0.7 * cmu.size)
    ref = refine_kernel(h0, unit, resid, cmu, n_est, 200, 0.01)
    assert ref.taps == 51 and ref.ridge is not None
    err = np.linalg.norm(ref.kernel[:51] - h_true[:51]) / np.linalg.norm(delta[:51])
    assert err < 0.1, err                                 # δh to within 10 % of its size
    np.testing.assert_array_equal(ref.kernel[51:], h0[51:])
    best = min(v for k, v in ref.holdout_rmse.items() if k != "single_burst")
    assert best < 0.5 * ref.holdout_rmse["single_burst"]


def test_refinement_keeps_the_single_burst_kernel_when_the_residual_is_not_in_its_span(rng):
    """White residual, nothing the kernel explains: held-out error says keep h as averaged."""
    from rtlift.identify.kernel import refine_kernel

    h0 = response(300)
    cmu = modulated_train(rng)
    resid = rng.normal(0, 1e-3, cmu.size)
    ref = refine_kernel(h0, cmu.copy(), resid, cmu, int(0.7 * cmu.size), 200, 0.01)
    assert ref.ridge is None and ref.to_dict()["used"] == "single_burst"
    np.testing.assert_array_equal(ref.kernel, h0)

"""Single-burst kernel: onsets, phase average, noise-floor cut, φ (paper eq. 1)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from rtlift.identify.kernel import burst_onsets, fit_kernel

FS = 400.0
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

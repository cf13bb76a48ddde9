"""Identify the hybrid model (eq. 11) from the standard campaign's three records.

    ΔCL(k) = HF(φ Σ_j h(j) Cμ(k−j)) + N(Cμ_env(k)) · C x(k),   x(k) = A x(k−1) + B Cμ_env(k)

1. static sweep → monotone map, N(Cμ) table, hysteresis report (:mod:`.static_map`);
2. single bursts → kernel h and φ (:mod:`.kernel`);
3. training record (the paper: the k = 0.125 sinusoid), split into an estimation part and a
   held-out tail: the HPF (:mod:`.highpass`) and then the Wiener order n = 1 … 4 are chosen
   by held-out RMSE of the whole hybrid; finally A, B, C are re-estimated by output-error PEM
   (:mod:`.pem`) on the whole training record with the chosen structure.
4. φ: the paper's φ makes the convolution reproduce the single-burst response. On a plant
   whose burst response weakens as the flow attaches, that φ over-predicts the ripple at high
   Cμ; the hybrid's output error is linear in φ, so PEM can re-estimate it jointly with C
   (φ_train = β φ_single). ``phi="auto"`` keeps whichever of the two has the lower held-out
   RMSE; both are recorded.

Pure: takes :class:`~rtlift.records.Record` objects, returns an :class:`Identification`
holding the :class:`~rtlift.hybrid.HybridModel` and plain dicts for the model file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import InputGain, OutputNonlinearity, WienerBlock
from rtlift.hybrid import HybridModel
from rtlift.identify.highpass import HighPassChoice, choose_highpass, wiener_fit_for_highpass
from rtlift.identify.kernel import SingleBurstKernel, burst_onsets, fit_kernel
from rtlift.identify.pem import OrderChoice, PEMResult, choose_order, fit_wiener
from rtlift.identify.static_map import StaticMap, fit_static_map
from rtlift.metrics import scores
from rtlift.records import Record

WIENER_FORMS = ("input_gain", "output_map")


@dataclass(frozen=True)
class IdentifyOptions:
    """Choices of the identification (defaults: the paper's structure, data-driven sizes)."""

    order: int | None = None                  # Wiener LTI order; None: choose 1 … max_order
    max_order: int = 4
    form: str = "input_gain"                  # or "output_map" (textbook Wiener, f = static map)
    holdout_fraction: float = 0.3
    skip_s: float = 0.5                       # initial transient left out of every cost
    hpf_orders: tuple[int, ...] = (1, 2, 3, 4)
    hpf_cutoffs_hz: tuple[float, ...] = (0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.5)
    hpf_search_order: int = 2                 # Wiener order used while choosing the HPF
    phi: str = "auto"                         # "single_burst" (paper), "train" or "auto"
    control_band_hz: float = 1.0              # HF must reject ≥ 20 dB up to here (k = 0.25)


@dataclass
class Identification:
    """Everything the identification produced."""

    model: HybridModel
    static: StaticMap
    kernel: SingleBurstKernel
    highpass: HighPassChoice
    order: OrderChoice
    pem: PEMResult
    provenance: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    observer: dict = field(default_factory=dict)


def _check_rate(records: list[Record]) -> float:
    rates = [r.fs_hz for r in records]
    if max(rates) - min(rates) > 1e-6 * max(rates):
        names = ", ".join(f"{r.name} {f:g} Hz" for r, f in zip(records, rates, strict=True))
        raise ValueError(f"records have different sample rates ({names})")
    return rates[0]


def nonlinearity_for(static: StaticMap, form: str):
    """The Wiener static part: N(Cμ) table (paper) or f(y) = static map (textbook)."""
    if form == "input_gain":
        return InputGain(static.gain_cmu, static.gain)
    return OutputNonlinearity(static.cmu, static.dcl)


def convolution_output(kernel: SingleBurstKernel, cmu: np.ndarray) -> np.ndarray:
    """φ Σ_j h(j) Cμ(k−j) from rest (paper eq. 1)."""
    return kernel.phi * signal.lfilter(kernel.kernel, [1.0], cmu)


def identify_hybrid(static_rec: Record, burst_rec: Record, train_rec: Record,
                    options: IdentifyOptions | None = None) -> Identification:
    """Identify the hybrid model (module docstring). Raises ``ValueError`` on unusable data."""
    opt = options or IdentifyOptions()
    if opt.form not in WIENER_FORMS:
        raise ValueError(f"unknown Wiener form {opt.form!r}; expected one of {WIENER_FORMS}")
    fs = _check_rate([static_rec, burst_rec, train_rec])
    static = fit_static_map(static_rec.cmu_envelope, static_rec.dcl, fs)
    kernel = fit_kernel(burst_rec.cmu, burst_rec.dcl, fs)

    env, dcl = train_rec.cmu_envelope, train_rec.dcl
    n = dcl.size
    n_est = int(round((1.0 - opt.holdout_fraction) * n))
    skip = int(round(opt.skip_s * fs))
    if n_est - skip < 20 * (opt.max_order + 2) or n - n_est < 10:
        raise ValueError(f"training record too short ({n} samples)")
    if opt.phi not in ("auto", "single_burst", "train"):
        raise ValueError(f"unknown phi choice {opt.phi!r}")
    gain = static.gain_at(env) if opt.form == "input_gain" else None
    table = (static.cmu, static.dcl) if opt.form == "output_map" else None
    conv = convolution_output(kernel, train_rec.cmu)

    modes = {"auto": (False, True), "single_burst": (False,), "train": (True,)}[opt.phi]
    searches = {refine: choose_highpass(conv, dcl, env, fs, n_est=n_est,
                                        wiener_order=opt.order or opt.hpf_search_order,
                                        gain=gain, table=table, form=opt.form, skip=skip,
                                        orders=opt.hpf_orders, cutoffs_hz=opt.hpf_cutoffs_hz,
                                        refine_phi=refine,
                                        control_band_hz=opt.control_band_hz)
                for refine in modes}
    refine = min(searches, key=lambda r: searches[r].holdout_rmse)
    hp = searches[refine]
    hpf = HighPassFilter.design(hp.order, hp.cutoff_hz, fs)
    high = hpf.simulate(conv)
    hpf.reset()

    orders = [opt.order] if opt.order else list(range(1, opt.max_order + 1))
    candidates = {}
    val = slice(n_est, n)
    for k in orders:
        res, dhat = wiener_fit_for_highpass(high, dcl, env, n_est, k, fs, gain, table, opt.form,
                                            skip, refine_phi=refine)
        candidates[k] = (res, float(np.sqrt(np.mean((dcl[val] - dhat[val]) ** 2))))
    choice = choose_order(candidates)
    pem = fit_wiener(env, dcl if refine else dcl - high, choice.order, form=opt.form, fs_hz=fs,
                     gain=gain, table=table, skip=skip, theta0=candidates[choice.order][0].theta,
                     extra=high if refine else None)
    phi = kernel.phi * (float(pem.extra_coef[0]) if refine else 1.0)

    lti = pem.lti
    wiener = WienerBlock(lti.A, lti.B, lti.C, nonlinearity_for(static, opt.form))
    model = HybridModel(RingConvolution(kernel.kernel, phi), hpf, wiener, fs)
    out = model.simulate(train_rec.cmu, train_rec.cmu_envelope)
    model.reset()
    resid = dcl - out.total
    noise_std = _quiet_noise_std(burst_rec, fs)

    train_scores = scores(dcl[skip:], out.total[skip:])
    metrics = {
        "train": {"record": train_rec.name, **train_scores},
        "holdout": {"fraction": opt.holdout_fraction,
                    "rmse": candidates[choice.order][1]},
        "residual_std_train": float(np.std(resid[skip:])),
        "residual_mean_train": float(np.mean(resid[skip:])),
        "measurement_noise_std": noise_std,
        "static_map_rmse": static.fit_rmse,
        "kernel_reproduction_nrmse": kernel.reproduction_nrmse,
        "pem_rmse": pem.rmse,
    }
    provenance = {
        "tool": "rtlift identify",
        "records": {"static": static_rec.name, "single_burst": burst_rec.name,
                    "train": train_rec.name},
        "fs_hz": fs,
        "static_map": {"cmu_max": static.cmu_max, "limit_slope": static.limit_slope,
                       "hysteresis": static.hysteresis.to_dict(), "notes": static.notes,
                       "beyond_range": "N held at its last value: ΔCL continues along the last "
                                       "chord through the origin",
                       "cmu_zero": "N(0) = limit slope of the map at the origin"},
        "kernel": kernel.to_dict(),
        "phi": phi,
        "phi_choice": {
            "used": "train" if refine else "single_burst",
            "phi_single_burst": kernel.phi,
            "phi_train": phi if refine else None,
            "holdout_rmse": {("train" if r else "single_burst"): searches[r].holdout_rmse
                             for r in searches},
        },
        "highpass": hp.to_dict(),
        "wiener": {
            "form": opt.form,
            "order": choice.order,
            "order_selection": {"rule": choice.rule, "candidates": choice.table},
            "estimation": "output-error PEM, Levenberg-Marquardt (scipy least_squares), "
                          "stable pole parametrisation, whole hybrid's output error",
            "poles": [[float(p.real), float(p.imag)] for p in lti.poles],
            "spectral_radius": lti.spectral_radius,
            "dc_gain": lti.dc_gain,
            "time_constants_s": [float(t) for t in lti.time_constants_s(fs)],
            "uncertainty": pem.uncertainty,
            "nfev": pem.nfev,
        },
    }
    if env.max() > static.cmu_max * 1.001:
        provenance["static_map"]["warning"] = (
            f"training envelope reaches {env.max():.4g}, beyond the static sweep's "
            f"{static.cmu_max:.4g}")
    observer = {"measurement_noise_std": noise_std,
                "model_residual_std": metrics["residual_std_train"]}
    return Identification(model, static, kernel, hp, choice, pem, provenance, metrics, observer)


def _quiet_noise_std(rec: Record, fs: float) -> float:
    """Std of ΔCL while no burst has fired for ≥ 2 s (sensor noise + buffeting at rest);
    falls back to the first 0.1 s of the record."""
    on = burst_onsets(rec.cmu)
    quiet = np.ones(rec.dcl.size, dtype=bool)
    reach = int(2.0 * fs)
    for o in on:
        quiet[o:o + reach] = False
    if quiet.sum() < 0.2 * fs:
        quiet[:] = False
        quiet[: max(int(0.1 * fs), 2)] = True
    return float(np.std(rec.dcl[quiet]))

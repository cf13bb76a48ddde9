"""Identify the hybrid model (eq. 11) from the standard campaign's three records.

    ΔCL(k) = HF(φ Σ_j h(j) Cμ(k−j)) + N(Cμ_env(k)) · C x(k),   x(k) = A x(k−1) + B Cμ_env(k)

1. static sweep → monotone map, N(Cμ) table, hysteresis report (:mod:`.static_map`);
2. single bursts → kernel h and φ (:mod:`.kernel`);
3. training record (the paper: the k = 0.125 sinusoid), split into an estimation part and a
   held-out tail: the HPF (:mod:`.highpass`) and then the Wiener order n = 1 … 4 are chosen
   by held-out RMSE of the whole hybrid; finally A, B, C are re-estimated by output-error PEM
   (:mod:`.pem`) on the whole training record with the chosen structure.
4. structure by held-out error (Ljung §16.4): the Wiener form (the paper's N(Cμ)·y or the
   textbook f(y) with f the static map) and a dead time D of the whole model (samples the
   measured lift lags the actuation record: DAQ and convective latency), 0 … ``max_dead_time``.
   HPF and order are searched per form with D = 0, every D is then scored with one PEM fit,
   and the chosen (form, D) is identified in full. The smallest D and the paper's form win
   ties within ``structure_tolerance``. D is stored as a ``delay`` input stage of kind
   structure (``provenance.structure``): a diagnosis reports a later delay on top of it.
5. φ: the paper's φ makes the convolution reproduce the single-burst response. On a plant
   whose burst response weakens as the flow attaches, that φ over-predicts the ripple at high
   Cμ; the hybrid's output error is linear in φ, so PEM can re-estimate it jointly with C
   (φ_train = β φ_single). ``phi="auto"`` keeps whichever of the two has the lower held-out
   RMSE; both are recorded. The Wiener PEM's cost also holds the static sweep (simulated
   from rest before the training record, thinned to weigh alike): the sine alone leaves
   the DC gain loose, the sweep pins it.
5b. the kernel's first burst period re-estimated on the training record
   (:func:`.kernel.refine_kernel`: thousands of bursts there against a few dozen in the
   single-burst record, so the burst harmonics come out right), kept where it lowers the
   held-out RMSE (``kernel="auto"``; the paper's ``"single_burst"`` keeps h as averaged).
6. the residual fingerprint of the final model on the three records
   (:mod:`rtlift.residual.fingerprint`), stored in the model file for later diagnoses, and
   the model's domain (burst periods and Cμ range of the three records, :mod:`rtlift.model.domain`).
7. the Wiener part's input (``envelope``; issue 47): the envelope as recorded (the default, the
   paper's), or as the bursts delivered it — the ``onset_hold`` stage
   (:mod:`rtlift.blocks.onset_hold`: the envelope at each burst onset, held to the next, 0 while
   it is 0), applied to the static sweep and the training record before steps 3–5 (the static
   map stays the recorded sweep's: 40 s ramps, the half period moves it by < 0.2 %) and stored
   as the model's last input stage, so the model computes it in every loop. A smooth envelope and
   one held per burst period (the loop's) then give the model the same input when they deliver
   the same bursts. ``"auto"`` identifies both and keeps the delivered one unless the recorded
   one's held-out RMSE is lower by more than ``structure_tolerance`` (twice the time).

Pure: takes :class:`~rtlift.core.records.Record` objects, returns an :class:`Identification`
holding the :class:`~rtlift.model.hybrid.HybridModel` and plain dicts for the model file.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal

from rtlift.blocks.convolution import RingConvolution
from rtlift.blocks.delay import Delay
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.onset_hold import OnsetHold
from rtlift.blocks.wiener import InputGain, OutputNonlinearity, WienerBlock
from rtlift.core.errors import require_finite
from rtlift.core.metrics import scores
from rtlift.core.records import Record
from rtlift.core.threads import one_blas_thread
from rtlift.identify.highpass import HighPassChoice, choose_highpass, wiener_fit_for_highpass
from rtlift.identify.kernel import KernelRefinement, SingleBurstKernel, burst_onsets, fit_kernel, refine_kernel
from rtlift.identify.order import OrderChoice, choose_order
from rtlift.identify.pem import PEMResult, fit_wiener
from rtlift.identify.static_map import StaticMap, fit_static_map
from rtlift.model.domain import domain_of, envelope_reach
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import FINGERPRINT_START_S, fingerprint

WIENER_FORMS = ("input_gain", "output_map")
ENVELOPES = ("recorded", "delivered", "auto")


@dataclass(frozen=True)
class IdentifyOptions:
    """Choices of the identification (defaults: structure and sizes chosen by held-out error)."""

    order: int | None = None                  # Wiener LTI order; None: choose 1 … max_order
    max_order: int = 4
    form: str = "auto"                        # "input_gain" (paper), "output_map" (textbook) or "auto"
    dead_time: int | None = None              # samples; None: choose 0 … max_dead_time
    max_dead_time: int = 8
    structure_tolerance: float = 0.01         # ties (relative held-out RMSE) go to the simpler
    static_in_cost: bool = True               # the static sweep shares the Wiener PEM's cost
    rest_s: float = 10.0                      # rest between the sweep and the training record
    holdout_fraction: float = 0.3
    skip_s: float = 0.5                       # initial transient left out of every cost
    hpf_orders: tuple[int, ...] = (1, 2, 3, 4)
    hpf_cutoffs_hz: tuple[float, ...] = (0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.5)
    hpf_search_order: int = 2                 # Wiener order used while choosing the HPF
    phi: str = "auto"                         # "single_burst" (paper), "train" or "auto"
    kernel: str = "auto"                      # "single_burst" (paper) or "auto": first period refined
    control_band_hz: float = 1.0              # HF must reject ≥ 20 dB up to here (k = 0.25)
    envelope: str = "recorded"                # the Wiener input: "recorded", "delivered" (onset_hold) or
                                              # "auto" (both identified, by held-out RMSE; step 7)


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


def delivered(rec: Record, fs: float) -> Record:
    """The record with its envelope replaced by what the bursts delivered (the ``onset_hold``
    stage from rest: the envelope at each burst onset, held to the next, 0 while it is 0)."""
    out = rec.slice(0, len(rec))
    out.cmu_envelope = OnsetHold(fs).simulate(rec.cmu, rec.cmu_envelope)[1]
    return out


def delayed(rec: Record, samples: int) -> Record:
    """The record with its actuation (Cμ, Cμ_env) arriving ``samples`` later (zeros before)."""
    if samples == 0:
        return rec
    out = rec.slice(0, len(rec))
    out.cmu = np.concatenate([np.zeros(samples), rec.cmu[:-samples]])
    out.cmu_envelope = np.concatenate([np.zeros(samples), rec.cmu_envelope[:-samples]])
    return out


@dataclass(frozen=True)
class _Joint:
    """The records the Wiener part is fitted on, laid end to end: [static sweep | rest |
    training record] (or the training record alone), every array delayed by the dead time.
    ``cost`` holds the fitted samples: the sweep's thinned so that it weighs like the training
    record's estimation part (its DC gain, which the sine alone leaves loose, is what it adds);
    the training record's last part (from ``n_est``) is the held-out part."""

    cmu: np.ndarray
    env: np.ndarray
    dcl: np.ndarray
    offset: int            # first sample of the training record
    n_est: int             # end of the estimation part (absolute index)
    cost: np.ndarray

    @property
    def holdout(self) -> slice:
        return slice(self.n_est, self.dcl.size)

    @property
    def train(self) -> slice:
        return slice(self.offset, self.dcl.size)


def _joint(static: Record | None, train: Record, dead_time: int, n_est: int, skip: int,
           rest: int) -> _Joint:
    parts = [delayed(train, dead_time)]
    if static is not None:
        pause = np.zeros(rest)
        st = delayed(static, dead_time)
        parts = [st, Record(pause, pause, pause, pause), parts[0]]
    cat = {k: np.concatenate([getattr(r, k) for r in parts]) for k in ("cmu", "cmu_envelope", "dcl")}
    offset = cat["dcl"].size - len(train)
    own = np.arange(offset + skip, offset + n_est)
    if static is None:
        cost = own
    else:
        stride = max(1, int(round((len(static) - skip) / max(own.size, 1))))
        cost = np.concatenate([np.arange(skip, len(static), stride), own])
    return _Joint(cat["cmu"], cat["cmu_envelope"], cat["dcl"], offset, offset + n_est, cost)


@dataclass
class _StructureFit:
    """One (form, dead time) identified on the training record's estimation part."""

    form: str
    dead_time: int
    hp: HighPassChoice
    refine: bool
    searches: dict
    candidates: dict
    choice: OrderChoice
    holdout_rmse: float


def _fit_structure(static: StaticMap, kernel: SingleBurstKernel, data: _Joint, opt: IdentifyOptions,
                   form: str, dead_time: int, skip: int, fs: float,
                   fixed: _StructureFit | None = None) -> _StructureFit:
    """HPF, φ choice and Wiener order by held-out RMSE for one structure; with ``fixed``, only
    the Wiener part is refitted with the HPF, φ choice and order of ``fixed`` (a cheap score)."""
    env, dcl = data.env, data.dcl
    gain = static.gain_at(env) if form == "input_gain" else None
    table = (static.cmu, static.dcl) if form == "output_map" else None
    conv = convolution_output(kernel, data.cmu)
    val, n_est = data.holdout, data.n_est
    if fixed is not None:
        hpf = HighPassFilter.design(fixed.hp.order, fixed.hp.cutoff_hz, fs)
        k = fixed.choice.order
        res, dhat = wiener_fit_for_highpass(hpf.simulate(conv), dcl, env, n_est, k, fs, gain, table, form,
                                            skip, refine_phi=fixed.refine, cost=data.cost)
        err = float(np.sqrt(np.mean((dcl[val] - dhat[val]) ** 2)))
        return _StructureFit(form, dead_time, fixed.hp, fixed.refine, fixed.searches,
                             {k: (res, err)}, fixed.choice, err)
    modes = {"auto": (False, True), "single_burst": (False,), "train": (True,)}[opt.phi]
    tr = data.train          # the HPF concerns the burst part: searched on the training record alone
    searches = {refine: choose_highpass(conv[tr], dcl[tr], env[tr], fs, n_est=n_est - data.offset,
                                        wiener_order=opt.order or opt.hpf_search_order,
                                        gain=None if gain is None else gain[tr], table=table, form=form,
                                        skip=skip, orders=opt.hpf_orders, cutoffs_hz=opt.hpf_cutoffs_hz,
                                        refine_phi=refine, control_band_hz=opt.control_band_hz)
                for refine in modes}
    refine = min(searches, key=lambda r: searches[r].holdout_rmse)
    hp = searches[refine]
    high = HighPassFilter.design(hp.order, hp.cutoff_hz, fs).simulate(conv)
    orders = [opt.order] if opt.order else list(range(1, opt.max_order + 1))
    candidates = {}
    for k in orders:
        res, dhat = wiener_fit_for_highpass(high, dcl, env, n_est, k, fs, gain, table, form,
                                            skip, refine_phi=refine, cost=data.cost)
        candidates[k] = (res, float(np.sqrt(np.mean((dcl[val] - dhat[val]) ** 2))))
    choice = choose_order(candidates)
    return _StructureFit(form, dead_time, hp, refine, searches, candidates, choice,
                         candidates[choice.order][1])


def _refine_kernel_under_highpass(model: HybridModel, train: Record, n_est: int, skip: int,
                                  opt: IdentifyOptions) -> KernelRefinement:
    """Step 5b (module docstring): :func:`.kernel.refine_kernel` on the training record, the
    rest of the model as identified. The paper's burst part ΔCL_H = HF(φ Σ_j h(j) Cμ(k − j)) is
    linear in h; its regressors are the model's ΔCL_H with the unit kernel h = e₀ (the high-pass
    of φ Cμ), delayed — unlike the interaction structure's, weighted by its gains
    (:func:`rtlift.identify.interaction._refine_kernel_under_gains`)."""
    h = model.convolution.kernel
    if opt.kernel == "single_burst":
        return KernelRefinement(h, 0, None, {})
    out = model.simulate(train.cmu, train.cmu_envelope)
    unit = model.copy()
    unit.convolution = RingConvolution(np.eye(1, h.size).ravel(), model.convolution.phi)
    unit_high = unit.simulate(train.cmu, train.cmu_envelope).high
    model.reset()
    return refine_kernel(h, unit_high, train.dcl - out.total, train.cmu, n_est, skip,
                         opt.structure_tolerance)


def _simplest_near_best(fits: list[_StructureFit], tolerance: float) -> _StructureFit:
    """The simplest structure within ``tolerance`` of the best held-out RMSE: the paper's form
    before the textbook one, then the smallest dead time (parsimony, Ljung §16.4)."""
    best = min(f.holdout_rmse for f in fits)
    near = [f for f in fits if f.holdout_rmse <= best * (1 + tolerance)]
    return min(near, key=lambda f: (WIENER_FORMS.index(f.form), f.dead_time))


@one_blas_thread
def identify_hybrid(static_rec: Record, burst_rec: Record, train_rec: Record,
                    options: IdentifyOptions | None = None) -> Identification:
    """Identify the hybrid model (module docstring). Raises ``ValueError`` on unusable data."""
    opt = options or IdentifyOptions()
    if opt.form not in (*WIENER_FORMS, "auto"):
        raise ValueError(f"unknown Wiener form {opt.form!r}; expected one of {(*WIENER_FORMS, 'auto')}")
    if opt.envelope not in ENVELOPES:
        raise ValueError(f"unknown envelope convention {opt.envelope!r}; expected one of {ENVELOPES}")
    if opt.dead_time is not None and not 0 <= opt.dead_time <= 10 * opt.max_dead_time:
        raise ValueError(f"dead time {opt.dead_time} samples is out of range")
    fs = _check_rate([static_rec, burst_rec, train_rec])
    static = fit_static_map(static_rec.cmu_envelope, static_rec.dcl, fs)
    require_finite("static map", static_rec.name, cmu=static.cmu, dcl=static.dcl, rmse=static.fit_rmse)
    kernel = fit_kernel(burst_rec.cmu, burst_rec.dcl, fs)
    require_finite("single-burst kernel", burst_rec.name, kernel=kernel.kernel, phi=kernel.phi)

    n = train_rec.dcl.size
    n_est = int(round((1.0 - opt.holdout_fraction) * n))
    skip = int(round(opt.skip_s * fs))
    if n_est - skip < 20 * (opt.max_order + 2) or n - n_est < 10:
        raise ValueError(f"training record too short ({n} samples)")
    if opt.phi not in ("auto", "single_burst", "train"):
        raise ValueError(f"unknown phi choice {opt.phi!r}")
    if opt.envelope == "auto":
        return _envelope_by_holdout(static_rec, burst_rec, train_rec, opt)
    hold = opt.envelope == "delivered" and burst_onsets(train_rec.cmu).size > 0
    fit_static, fit_train = (delivered(static_rec, fs), delivered(train_rec, fs)) if hold else (static_rec, train_rec)
    forms = WIENER_FORMS if opt.form == "auto" else (opt.form,)
    dead_times = range(opt.max_dead_time + 1) if opt.dead_time is None else (opt.dead_time,)
    sweep = fit_static if opt.static_in_cost else None
    rest = int(round(opt.rest_s * fs))

    def data(d: int) -> _Joint:
        return _joint(sweep, fit_train, d, n_est, skip, rest)

    first = {form: _fit_structure(static, kernel, data(dead_times[0]), opt, form, dead_times[0], skip, fs)
             for form in forms}
    scored = [first[form] if d == dead_times[0] else
              _fit_structure(static, kernel, data(d), opt, form, d, skip, fs, fixed=first[form])
              for form in forms for d in dead_times]
    require_finite("structure search (high-pass, Wiener order)", train_rec.name,
                   holdout_rmse=[f.holdout_rmse for f in scored])
    pick = _simplest_near_best(scored, opt.structure_tolerance)
    fit = first[pick.form] if pick.dead_time == dead_times[0] else \
        _fit_structure(static, kernel, data(pick.dead_time), opt, pick.form, pick.dead_time, skip, fs)
    form, dead_time, hp, refine, choice = fit.form, fit.dead_time, fit.hp, fit.refine, fit.choice

    joint = data(dead_time)
    full = np.concatenate([joint.cost[joint.cost < joint.offset], np.arange(joint.offset + skip, joint.dcl.size)])
    env, dcl = joint.env, joint.dcl
    gain = static.gain_at(env) if form == "input_gain" else None
    table = (static.cmu, static.dcl) if form == "output_map" else None
    hpf = HighPassFilter.design(hp.order, hp.cutoff_hz, fs)
    high = hpf.simulate(convolution_output(kernel, joint.cmu))
    hpf.reset()
    pem = fit_wiener(env, dcl if refine else dcl - high, choice.order, form=form, fs_hz=fs,
                     gain=gain, table=table, skip=skip, theta0=fit.candidates[choice.order][0].theta,
                     extra=high if refine else None, cost=full)
    require_finite("Wiener PEM", train_rec.name, a=pem.lti.a, c=pem.lti.c, rmse=pem.rmse,
                   extra_coef=pem.extra_coef, uncertainty=pem.uncertainty)
    phi = kernel.phi * (float(pem.extra_coef[0]) if refine else 1.0)

    lti = pem.lti
    wiener = WienerBlock(lti.A, lti.B, lti.C, nonlinearity_for(static, form))
    stages = ((Delay(dead_time / fs, fs),) if dead_time else ()) + ((OnsetHold(fs),) if hold else ())
    model = HybridModel(RingConvolution(kernel.kernel, phi), hpf, wiener, fs, input_stages=stages)
    refined = _refine_kernel_under_highpass(model, train_rec, n_est, skip, opt)
    model.convolution = RingConvolution(refined.kernel, phi)
    out = model.simulate(train_rec.cmu, train_rec.cmu_envelope)
    model.reset()
    require_finite("kernel refinement and simulation", train_rec.name, kernel=refined.kernel, output=out.total)
    dcl = train_rec.dcl
    resid = dcl - out.total
    noise_std = quiet_noise_std(burst_rec, fs)

    train_scores = scores(dcl[skip:], out.total[skip:])
    metrics = {
        "train": {"record": train_rec.name, **train_scores},
        "holdout": {"fraction": opt.holdout_fraction,
                    "rmse": fit.candidates[choice.order][1]},
        **fit_metrics(resid[skip:], noise_std, static, kernel, pem),
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
        "kernel": {**kernel.to_dict(), "refinement": refined.to_dict()},
        "phi": phi,
        "domain": {**domain_of([static_rec, burst_rec, train_rec], fs, kernel.kernel.size),
                   "train_envelope": envelope_reach(train_rec.cmu_envelope, fs)},
        "phi_choice": {
            "used": "train" if refine else "single_burst",
            "phi_single_burst": kernel.phi,
            "phi_train": phi if refine else None,
            "holdout_rmse": {("train" if r else "single_burst"): fit.searches[r].holdout_rmse
                             for r in fit.searches},
        },
        "highpass": hp.to_dict(),
        "structure": {
            "form": form,
            "dead_time_samples": dead_time,
            "static_in_cost": opt.static_in_cost,
            "envelope": "delivered (onset_hold: the envelope at each burst onset, held to the next)" if hold
                        else "recorded",
            "rule": f"by held-out RMSE of the training record's last {100 * opt.holdout_fraction:.0f} %; "
                    f"the paper's form and the smaller dead time within "
                    f"{100 * opt.structure_tolerance:.0f} % of the best",
            "candidates": [{"form": f.form, "dead_time_samples": f.dead_time, "holdout_rmse": f.holdout_rmse}
                           for f in scored],
        },
        "wiener": {
            "form": form,
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
    model.fingerprint = fingerprint(model, [train_rec, static_rec, burst_rec],
                                    int(round(FINGERPRINT_START_S * fs)))
    require_finite("residual fingerprint", f"{train_rec.name}, {static_rec.name}, {burst_rec.name}",
                   fingerprint=model.fingerprint, metrics=metrics)
    observer = {"measurement_noise_std": noise_std,
                "model_residual_std": metrics["residual_std_train"]}
    return Identification(model, static, kernel, hp, choice, pem, provenance, metrics, observer)


def _envelope_by_holdout(static_rec: Record, burst_rec: Record, train_rec: Record,
                         opt: IdentifyOptions) -> Identification:
    """Step 7 (module docstring): the model identified with each Wiener input; the delivered
    envelope's unless the recorded one's held-out RMSE is lower by more than ``structure_tolerance``."""
    both = {e: identify_hybrid(static_rec, burst_rec, train_rec, replace(opt, envelope=e))
            for e in ("delivered", "recorded")}
    err = {e: float(idf.metrics["holdout"]["rmse"]) for e, idf in both.items()}
    pick = "delivered" if err["delivered"] <= err["recorded"] * (1 + opt.structure_tolerance) else "recorded"
    idf = both[pick]
    idf.provenance["structure"]["envelope_choice"] = {
        "used": pick, "holdout_rmse": err,
        "rule": f"by held-out RMSE of the training record's last {100 * opt.holdout_fraction:.0f} %; the delivered "
                f"envelope (the loop's convention) within {100 * opt.structure_tolerance:.0f} % of the recorded one"}
    return idf


def fit_metrics(resid: np.ndarray, noise_std: float, static: StaticMap, kernel: SingleBurstKernel,
                pem: PEMResult) -> dict[str, float]:
    """The fit metrics every lift model file holds: the residual on the training record (its
    scored part), the sensor noise, and the static map's, kernel's and PEM's own errors."""
    return {"residual_std_train": float(np.std(resid)), "residual_mean_train": float(np.mean(resid)),
            "measurement_noise_std": noise_std, "static_map_rmse": static.fit_rmse,
            "kernel_reproduction_nrmse": kernel.reproduction_nrmse, "pem_rmse": pem.rmse}


def quiet_noise_std(rec: Record, fs: float) -> float:
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

"""Validation of a model on records: the paper's protocol and metrics, and figures.

Per record the model is run open loop from rest over the whole record (the same
``HybridModel.simulate`` a controller's prediction uses) and scored against the measured
ΔCL with ρ (the paper's correlation coefficient), NRMSE = RMSE/σ(ΔCL) and RMSE
(:func:`rtlift.core.metrics.scores`). :func:`predict_record` is the one prediction every score in
rtlift comes from (``rtlift validate`` and ``rtlift diagnose`` alike): a pickup's phases are
a property of the record, not of the pickup, and it estimates them on the record itself.
The JSON layout is INTERFACES.md's:
``{"version": 1, "model": path, "records": {stem: {"corr", "nrmse", "rmse"}}}``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import Record, SisoRecord
from rtlift.model.hybrid import HybridModel, HybridOutput

VALIDATE_VERSION = 1


@dataclass(frozen=True)
class RecordValidation:
    """One record's scores and the model's output (total, high, low)."""

    name: str
    scores: dict[str, float]
    output: HybridOutput | np.ndarray          # a generic model's output: one array


def simulate_record(model: HybridModel, record: Record) -> HybridOutput:
    """Open-loop model output over ``record`` from rest; the model is left reset."""
    model.reset()
    out = model.simulate(record.cmu, record.cmu_envelope)
    model.reset()
    return out


def per_record_stages(model: HybridModel) -> list:
    """The output stages with parameters of the record's own (the stage's ``per_record``: a
    pickup's line phases)."""
    return [s for s in model.output_stages if getattr(s, "per_record", ()) == ("phase_rad",)]


def pickup_phases(model: HybridModel, record: Record, total: np.ndarray) -> list[np.ndarray]:
    """Per ``periodic_disturbance`` stage, the phases φ_i of its lines on this record: with
    r = ΔCL − (ŷ − d), d the pickup the model adds, the least-squares fit
    r ≈ Σ_i a_i sin ω_i k + b_i cos ω_i k over the whole record (all lines of all stages at
    once) gives φ_i = atan2(b_i, a_i); amplitudes and frequencies stay the model's."""
    stages = per_record_stages(model)
    if not stages:
        return []
    n = total.size
    k = np.arange(n)
    d = np.zeros(n)
    for s in stages:
        s.reset()
        d += s.disturbance(n)
        s.reset()
    omegas = np.concatenate([s.omegas for s in stages])
    X = np.empty((n, 2 * omegas.size))
    for i, w in enumerate(omegas):
        X[:, 2 * i], X[:, 2 * i + 1] = np.sin(w * k), np.cos(w * k)
    coef, *_ = np.linalg.lstsq(X, record.dcl - (total - d), rcond=None)
    phases = np.arctan2(coef[1::2], coef[0::2])
    sizes = np.cumsum([0] + [s.omegas.size for s in stages])
    return [phases[a:b] for a, b in zip(sizes[:-1], sizes[1:], strict=True)]


def predict_record(model: HybridModel, record: Record) -> HybridOutput:
    """The open-loop prediction every score uses: :func:`simulate_record`, with each pickup's
    line phases set to the record's own (:func:`pickup_phases`; nothing else is taken from
    the measured ΔCL)."""
    out = simulate_record(model, record)
    stages = per_record_stages(model)
    if not stages:
        return out
    total = out.total.copy()
    n = total.size
    for s, phases in zip(stages, pickup_phases(model, record, out.total), strict=True):
        s.reset()
        total -= s.disturbance(n)
        own = s.with_phases(phases)
        total += own.disturbance(n)
        s.reset()
    return HybridOutput(total, out.high, out.low)


def validate_record(model: HybridModel, record: Record, skip: int = 0) -> RecordValidation:
    """ρ, NRMSE and RMSE of the model's ΔCL (:func:`predict_record`) against the record's, from
    sample ``skip`` on (the model runs from rest over the whole record)."""
    out = predict_record(model, record)
    return RecordValidation(record.name, scores(record.dcl[skip:], out.total[skip:]), out)


def validation_json(model_path: str, results: list[RecordValidation]) -> dict:
    """The validate JSON of INTERFACES.md."""
    return {"version": VALIDATE_VERSION, "model": str(model_path),
            "records": {r.name: {k: float(r.scores[k]) for k in ("corr", "nrmse", "rmse")}
                        for r in results}}


def plot_validation(record: Record, result: RecordValidation, path: str | os.PathLike,
                    title: str | None = None) -> None:
    """Figure: measured vs model ΔCL (top), the two parts of the hybrid (middle: ΔCL_H the
    high-passed convolution, ΔCL_L the Wiener part) and the envelope Cμ (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = record.t - record.t[0]
    out = result.output
    s = result.scores
    fig, ax = plt.subplots(3, 1, figsize=(10, 7), sharex=True,
                           gridspec_kw={"height_ratios": [3, 2, 1]})
    ax[0].plot(t, record.dcl, color="tab:blue", lw=0.6, label="measured ΔCL")
    ax[0].plot(t, out.total, color="tab:red", lw=0.9, label="hybrid model")
    ax[0].set_ylabel("ΔCL")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(title or f"{record.name}: ρ = {s['corr']:.4f}, NRMSE = {s['nrmse']:.3f}, "
                             f"RMSE = {s['rmse']:.4f}", fontsize=10)
    ax[1].plot(t, out.low, color="tab:green", lw=0.9, label="Wiener part ΔCL_L")
    ax[1].plot(t, out.high, color="tab:purple", lw=0.6, label="high-passed convolution ΔCL_H")
    ax[1].axhline(0.0, color="0.6", lw=0.5)
    ax[1].set_ylabel("parts")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(t, record.cmu_envelope, color="0.3", lw=0.8)
    ax[2].set_ylabel("Cμ envelope")
    ax[2].set_xlabel("t (s)")
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_generic_validation(record: SisoRecord, result: RecordValidation, path: str | os.PathLike,
                            skip: int = 0) -> None:
    """Figure for a generic ``t,u,y`` record (``result.output``: the model's free-run output):
    measured vs model (top), the residual (middle) and the input u (bottom); the first ``skip``
    samples, left out of the scores, shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = record.t - record.t[0]
    predicted, s = np.asarray(result.output), result.scores
    fig, ax = plt.subplots(3, 1, figsize=(10, 7), sharex=True, gridspec_kw={"height_ratios": [3, 2, 1]})
    ax[0].plot(t, record.y, color="tab:blue", lw=0.6, label="measured y")
    ax[0].plot(t, predicted, color="tab:red", lw=0.9, label="model (free run from rest)")
    ax[0].set_ylabel("y")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{record.name}: ρ = {s['corr']:.4f}, NRMSE = {s['nrmse']:.3f}, RMSE = {s['rmse']:.4g}",
                    fontsize=10)
    ax[1].plot(t, record.y - predicted, color="tab:gray", lw=0.6)
    ax[1].axhline(0.0, color="0.6", lw=0.5)
    ax[1].set_ylabel("residual")
    ax[2].plot(t, record.u, color="0.3", lw=0.8)
    ax[2].set_ylabel("u")
    ax[2].set_xlabel("t (s)")
    for a in ax:
        a.grid(alpha=0.3)
        if skip > 0:
            a.axvspan(t[0], t[min(skip, len(t) - 1)], color="0.9", zorder=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


"""What every fit shares: the :class:`Fitted` result, the fit's :class:`Context`, and the model
surgery (a model with one more stage or another Wiener nonlinearity, its prediction, its parts,
φ and the Wiener scale re-estimated with the effects in)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rtlift.blocks.delivered import STRUCTURE_STAGES
from rtlift.blocks.interaction import InteractionConvolution
from rtlift.blocks.stage_base import InputStage, OutputStage
from rtlift.core.records import Record
from rtlift.model.hybrid import HybridModel, HybridOutput
from rtlift.model.modelfile import model_from_dict, model_to_dict
from rtlift.model.validation import predict_record
from rtlift.residual.stats import TestResult


@dataclass
class Fitted:
    name: str
    model: HybridModel
    params: dict[str, Any]
    note: str = ""
    on_bound: str = ""             # which parameter ended on a bound of its range ("" if none)


@dataclass
class Context:
    fs: float
    start: int                                   # first sample of every residual test
    tests: dict[str, TestResult] = field(default_factory=dict)   # on the training residual
    fingerprint: dict[str, Any] | None = None    # the model's print for the training record's type
    input_lines_hz: tuple[float, ...] = ()       # burst and envelope harmonics (input-locked)


# ------------------------------------------------------------------ model surgery
def augment(model: HybridModel, *, input_stage: InputStage | None = None,
            output_stage: OutputStage | None = None, nonlinearity: Any = None,
            lti: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> HybridModel:
    """A fresh copy of ``model`` with one more stage (an input stage after the effects' input
    stages, before the interaction structure's own, :data:`~rtlift.blocks.delivered.STRUCTURE_STAGES`;
    filters before additive output stages) or another Wiener nonlinearity."""
    d = model_to_dict(model)
    if input_stage is not None:            # before the structure's own stages: it acts on the actuation they see
        stages = d["input_stages"]
        at = next((i for i, s in enumerate(stages) if s["name"] in STRUCTURE_STAGES), len(stages))
        stages.insert(at, {"name": input_stage.name, "params": input_stage.params()})
    if output_stage is not None:
        entry = {"name": output_stage.name, "params": output_stage.params()}
        stages = d["output_stages"]
        if output_stage.kind == "filter":
            first_additive = next((i for i, s in enumerate(model.output_stages) if s.kind == "additive"),
                                  len(stages))
            stages.insert(first_additive, entry)
        else:
            stages.append(entry)
    if nonlinearity is not None:
        d["wiener"]["nonlinearity"] = nonlinearity.to_dict()
    if lti is not None:
        d["wiener"].update(A=np.asarray(lti[0]).tolist(), B=np.asarray(lti[1]).tolist(),
                           C=np.asarray(lti[2]).tolist())
    return model_from_dict(d, allow_unstable=not model.stable)


def predict(model: HybridModel, rec: Record) -> HybridOutput:
    """The open-loop prediction every score uses (:func:`rtlift.model.validation.predict_record`)."""
    return predict_record(model, rec)


def filter_chain(model: HybridModel) -> Callable[[np.ndarray], np.ndarray]:
    """F: the model's filter-kind output stages (linear), applied from rest."""
    filters = [s for s in model.output_stages if s.kind == "filter"]

    def apply(x: np.ndarray) -> np.ndarray:
        for s in filters:
            s.reset()
            x = s.simulate(x)
            s.reset()
        return x
    return apply


def wiener_parts(model: HybridModel, rec: Record) -> tuple[np.ndarray, np.ndarray]:
    """(Cμ_env after the input stages, y = C x) on a record, from rest."""
    model.reset()
    _, env = model.inputs_simulate(rec.cmu, rec.cmu_envelope)
    y = model.wiener.lti.simulate(env)
    model.reset()
    return env, y


def burst_slow(model: HybridModel, rec: Record) -> np.ndarray:
    """The slow lift the model carries outside its Wiener part on a record, from rest: the
    interaction structure's burst slow term G(m)(c − HF c) + S(u)u (zeros in the paper's
    structure, whose burst part is high-passed)."""
    if type(model.convolution) is not InteractionConvolution:
        return np.zeros(rec.dcl.size)
    model.reset()
    _, slow = model.convolution.simulate_parts(*model.inputs_simulate(rec.cmu, rec.cmu_envelope))
    model.reset()
    return slow


def output_sse(model: HybridModel, rec: Record, start: int) -> float:
    return float(np.sum((rec.dcl - predict(model, rec).total)[start:] ** 2))


def at_bound(value: float, lo: float, hi: float, what: str, rel: float = 0.01) -> str:
    span = hi - lo
    if value <= lo + rel * span or value >= hi - rel * span:
        return f"{what} = {value:.4g} ended on its bound [{lo:g}, {hi:g}]"
    return ""


def rescaled(model: HybridModel, beta_high: float, beta_low: float) -> HybridModel:
    """A copy with φ scaled by ``beta_high`` and the Wiener part's static map (N or f, table
    values) by ``beta_low``."""
    d = model_to_dict(model)
    d["convolution"]["phi"] = float(d["convolution"]["phi"]) * beta_high
    nl = d["wiener"]["nonlinearity"]
    key = "gain" if "gain" in nl else "f"
    nl[key] = (np.asarray(nl[key]) * beta_low).tolist()
    return model_from_dict(d, allow_unstable=not model.stable)


def reestimate(model: HybridModel, train: Record, start: int) -> tuple[HybridModel, dict[str, float]]:
    """Point 5 of closing the loop: with the effects in, φ and the Wiener part's scale are
    re-estimated jointly on the training record. ŷ is linear in both (the effect stages are
    fixed and linear in ΔCL_H, ΔCL_L, or act on the input), so one least-squares solve:
    ΔCL − ŷ₀ ≈ (β_h − 1) ŷ_H + (β_l − 1) ŷ_L, ŷ_H and ŷ_L the model's output with only the
    burst part or only the Wiener part switched on."""
    base = predict(model, train).total
    only_high = predict(rescaled(model, 1.0, 0.0), train).total - predict(rescaled(model, 0.0, 0.0), train).total
    only_low = predict(rescaled(model, 0.0, 1.0), train).total - predict(rescaled(model, 0.0, 0.0), train).total
    X = np.column_stack([only_high, only_low])[start:]
    (bh, bl), *_ = np.linalg.lstsq(X, (train.dcl - base)[start:], rcond=None)
    beta_h, beta_l = 1.0 + float(bh), 1.0 + float(bl)
    return rescaled(model, beta_h, beta_l), {"phi_scale": beta_h, "wiener_scale": beta_l}

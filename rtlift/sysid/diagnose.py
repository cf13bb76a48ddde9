"""What a single-input Wiener model lacks, from its residual; added with joint re-estimation.

Residual ε = y − ŷ (free run from rest, the first ``skip`` samples unscored) on the training
record, tested as in :mod:`rtlift.residual.stats`: whiteness, correlation with past input
(missed linear dynamics) and the Billings–Voon higher-order correlations with u² and ŷ² (a
missed nonlinear structure: the linear tests barely react while these do).

Candidate structure (kind ``structure``: the model's form is too simple, not a new event):

- ``output_dynamics`` — a linear block after the static map: Wiener becomes Wiener–Hammerstein.
  Not a block glued after the frozen Wiener fit: the whole model is re-identified from the
  best linear approximation, its poles and zeros split between G₁ and G₂, f and both blocks
  refined jointly (:func:`rtlift.sysid.identify.identify_siso`).
- ``nonlinear_feedback`` — the output fed back through a static map into the linear block's
  input (an amplitude-dependent resonance, Duffing-like), identified jointly from the ARX fit.
- ``saturation`` — a hard limit on the output, y = min(max(M(u), lower), upper), or on the
  state, a store that cannot fill beyond its brim: the nonlinear-feedback recursion clipped
  inside the loop (:class:`rtlift.model.siso.FeedbackModel`), or two stores in cascade, each
  draining through a power-law outflow of its own level, the upper one spilling a share of what
  would rise above its brim into the lower one, whose brim is the level the measurement piles up
  at (:class:`rtlift.model.siso.StoreChainModel`: the nonlinear feedback of each state; Cascaded
  Tanks' two tanks, Torricelli outflows, overflow). Tried only where the evidence
  points to it, a measured output that piles up at a level (its maximum or minimum taken by
  ≥ 0.5 % and ≥ 5 of the training samples, which a continuous sensor reading a signal that only
  passes through its extremes does not do). M is re-identified jointly with the limit in place
  (:func:`rtlift.sysid.identify.identify_siso`; censored samples for an output limit) in each
  of the three forms with an output limit and in the two forms with a state limit; the one
  with the lowest validation error stands for ``saturation``, its form in ``params.model`` and
  ``params.where``. A limit on the input is not a separate structure: a Wiener model's static
  map f already saturates where the input's effect does.

Of the candidates that pass, the one with the lower validation error is added.

It is accepted only if it lowers the pooled error on the validation records significantly
(:func:`rtlift.diagnose.selection.significant_gain`, the rule the lift diagnosis uses: ≥ 1.5 %
RMSE, Diebold–Mariano t ≥ 3 over blocks, no record worse by more than 1 %).
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import SisoRecord
from rtlift.core.registry import STRUCTURES
from rtlift.core.threads import one_blas_thread
from rtlift.diagnose.selection import DiagnoseOptions, significant_gain
from rtlift.model.siso import FeedbackModel, SaturatedModel, SisoModel, StoreChainModel
from rtlift.residual.stats import higher_order, input_crosscorr, whiteness
from rtlift.sysid.identify import NO_LIMITS, Limits, SisoOptions, identify_siso
from rtlift.sysid.initial import initial_state

HOW = {e.name: e.how for e in STRUCTURES}
"""How each structure of the registry (:mod:`rtlift.core.registry`) is fitted, for the report."""
SATURATION = next(e for e in STRUCTURES if any(where for _, where in e.forms))
"""The structure that limits (``saturation``): tried only where the output piles up at a level."""
FORMS = tuple((e.name, e.forms[0][0]) for e in STRUCTURES if e is not SATURATION)
SATURATED_FORMS = SATURATION.forms
CLIP_MIN_FRACTION = 0.005
CLIP_MIN_SAMPLES = 5


def clip_levels(y: np.ndarray, e: np.ndarray | None = None) -> tuple[Limits, str]:
    """The levels the measured output piles up at (module docstring): (lower, upper), ±inf where
    there is none, and what the evidence says (with the residual ``e`` at and off the levels)."""
    y = np.asarray(y, dtype=float)
    tol = 1e-9 * max(float(np.ptp(y)), 1e-300)
    need = max(CLIP_MIN_SAMPLES, int(np.ceil(CLIP_MIN_FRACTION * y.size)))
    at_hi, at_lo = y >= y.max() - tol, y <= y.min() + tol
    lo = float(y.min()) if at_lo.sum() >= need else -np.inf
    hi = float(y.max()) if at_hi.sum() >= need else np.inf
    detail = (f"{int(at_hi.sum())} of {y.size} training samples at the maximum {y.max():.6g}, "
              f"{int(at_lo.sum())} at the minimum {y.min():.6g} (a limit needs {need})")
    at = (at_hi if np.isfinite(hi) else False) | (at_lo if np.isfinite(lo) else False)
    if e is not None and np.any(at) and not np.all(at):
        rms = lambda v: float(np.sqrt(np.mean(v**2)))   # noqa: E731
        detail += f"; residual RMS {rms(e[at]):.4g} at the limit, {rms(e[~at]):.4g} elsewhere"
    return (lo, hi), detail


def _structure_params(model, limited: bool = True) -> dict[str, Any]:
    """The report's params of a model; a limited one's limits with its own params under
    ``model_params``."""
    if isinstance(model, SaturatedModel):
        return {**model.limits(), "model": model.structure, "model_params": _structure_params(model.inner)}
    if isinstance(model, StoreChainModel):
        return {**model.limits(), "model": model.structure, "model_params": model.to_dict()["params"]}
    if isinstance(model, FeedbackModel) and model.limited and limited:
        return {**model.limits(), "model": model.structure, "model_params": _structure_params(model, False)}
    if model.structure == "nonlinear_feedback":
        return {"feedback": {"k2": float(model.k[0]), "k3": float(model.k[1])}, "offset": model.offset,
                "feedthrough": model.b0,
                "order": model.n,
                "poles": [[float(p.real), float(p.imag)] for p in np.roots(np.concatenate([[1.0], model.a]))]}
    if model.structure == "wiener":
        b1, a1 = model.g1.ba
        return {"poles": [[float(p.real), float(p.imag)] for p in np.roots(a1)], "order": int(a1.size - 1)}
    b2, a2 = model.g2.ba
    return {"poles": [[float(p.real), float(p.imag)] for p in np.roots(a2)],
            "zeros": [[float(z.real), float(z.imag)] for z in np.roots(b2)], "order": int(a2.size - 1)}


def predict(model: SisoModel, rec: SisoRecord, init: int = 0) -> np.ndarray:
    """Free-run output over the record from rest, or with ``init`` > 0 from the state estimated on
    the record's first ``init`` samples (:func:`rtlift.sysid.initial.initial_state`); the model is
    left reset."""
    model.reset()
    if init > 0:
        model.set_state(initial_state(model, rec.u, rec.y, init))
    out = model.simulate(rec.u)
    model.reset()
    return out


def record_scores(model: SisoModel, rec: SisoRecord, skip: int, init_state: bool = False) -> dict[str, float]:
    """ρ, NRMSE, RMSE from sample ``skip`` on (``rtlift validate --skip``); with ``init_state`` the
    state at the start estimated on the unscored samples (``--init-state``)."""
    return scores(rec.y[skip:], predict(model, rec, skip if init_state else 0)[skip:])


@one_blas_thread
def diagnose_siso(model: SisoModel, train: SisoRecord, validate: list[SisoRecord],
                  skip: int = 0, options: SisoOptions | None = None,
                  validate_skip: list[int] | None = None,
                  init_state: bool = False) -> tuple[dict[str, Any], SisoModel]:
    """The report (INTERFACES.md schema) and the augmented model (module docstring).
    ``validate_skip``: per validation record, the samples left unscored (default ``skip``; one
    long run's validation part is the whole run scored after its training part). ``init_state``:
    every model runs over a record from the state estimated on its unscored samples
    (:func:`rtlift.sysid.initial.initial_state`) instead of from rest."""
    vskip = list(validate_skip) if validate_skip is not None else [skip] * len(validate)
    init = (lambda k: k) if init_state else (lambda k: 0)   # noqa: E731
    e = train.y - predict(model, train, init(skip))
    s = max(skip, 1)
    tests = {"whiteness": whiteness(e[s:]), "input_crosscorr": input_crosscorr(e[s:], train.u[s:], label="u")}
    for t in higher_order(e[s:], train.u[s:], (train.y - e)[s:]):
        tests[t.name] = t
    evidence = "; ".join(f"{k} ({t.verdict}): {t.detail}" for k, t in tests.items()
                         if k in ("input_crosscorr", "bv_u2_e", "bv_y2_e"))
    # blocks for the significance test: about 40 over the validation data (the residual's
    # correlation time is the system's, unknown here; a lift record's 1 s blocks are 400 samples)
    block = max(50, sum(len(r) - k for r, k in zip(validate, vskip, strict=True)) // 40)
    before = [(r.y - predict(model, r, init(k)))[k:] for r, k in zip(validate, vskip, strict=True)]
    rb = float(np.sqrt(np.mean(np.concatenate(before) ** 2)))
    effects = []
    augmented = model
    not_built = []
    if model.structure == "wiener" and not isinstance(model, SaturatedModel):
        measured = np.concatenate([r.y[k:] for r, k in zip(validate, vskip, strict=True)])
        limits, clip_evidence = clip_levels(train.y, e)
        candidates = [(name, lambda structure=structure: identify_siso(train, structure, options=options))
                      for name, structure in FORMS]
        if limits != NO_LIMITS:
            candidates.append((SATURATION.name,
                               lambda: _best_saturated(train, validate, vskip, options, limits, init_state)))
        tried = []
        for name, fit in candidates:
            candidate = fit()
            after = [(r.y - predict(candidate, r, init(k)))[k:] for r, k in zip(validate, vskip, strict=True)]
            ok, why = significant_gain(before, after, measured, block, DiagnoseOptions())
            ra = float(np.sqrt(np.mean(np.concatenate(after) ** 2)))
            tried.append((ok, ra, candidate))
            effects.append({"name": name, "kind": "structure", "accepted": False,
                            "params": _structure_params(candidate),
                            "evidence": (f"{clip_evidence}; {HOW[name]} (best form: {candidate.structure}, "
                                         f"limit on the {candidate.limits()['where']}); {why}"
                                         if name == SATURATION.name else f"{evidence}; {HOW[name]}; {why}"),
                            "validation_rmse_before": rb, "validation_rmse_after": ra})
        admissible = [i for i, (ok, _, _) in enumerate(tried) if ok]
        if admissible:                                    # the better of the admissible structures
            k = min(admissible, key=lambda i: tried[i][1])
            effects[k]["accepted"] = True
            augmented = tried[k][2]
        if limits == NO_LIMITS:
            effects.append({"name": SATURATION.name, "kind": "structure", "accepted": False,
                            "params": {"lower": None, "upper": None, "where": "output"},
                            "evidence": f"not tried: no clipping level ({clip_evidence})",
                            "validation_rmse_before": rb, "validation_rmse_after": rb})
    unexplained = [f"{k}: {t.detail}" for k, t in tests.items() if t.significant] if augmented is model else []
    records = [(train, skip), *zip(validate, vskip, strict=True)]
    report = {
        "version": 1,
        "baseline": {"records": {r.name: record_scores(model, r, k, init_state) for r, k in records}},
        "augmented": {"records": {r.name: record_scores(augmented, r, k, init_state) for r, k in records}},
        "effects": effects,
        "unexplained": unexplained,
        "scoring": (f"free run over whole records from the state estimated on the first {skip} samples, "
                    "which are unscored (rtlift validate --skip --init-state)" if init_state else
                    f"free run from rest over whole records, the first {skip} samples unscored "
                    "(rtlift validate --skip)"),
        "not_built": not_built,
    }
    return report, augmented


def _best_saturated(train: SisoRecord, validate: list[SisoRecord], skip: list[int], options: SisoOptions | None,
                    limits: Limits, init_state: bool = False) -> SaturatedModel | FeedbackModel | StoreChainModel:
    """The ``saturation`` candidate: each form re-identified with the limit in place; the one with
    the lowest pooled validation RMSE (a form the record cannot have, a store chain fed by an input
    of negative mean, is left out)."""
    best = None
    for structure, where in SATURATED_FORMS:
        try:
            m = identify_siso(train, structure, options=options, limits=limits, where=where)
        except ValueError:
            continue
        err = float(np.sqrt(np.mean(np.concatenate([(r.y - predict(m, r, k if init_state else 0))[k:]
                                                    for r, k in zip(validate, skip, strict=True)]) ** 2)))
        if best is None or err < best[0]:
            best = (err, m)
    return best[1]


def write_report(report: dict[str, Any], augmented: SisoModel, out: str | os.PathLike) -> None:
    """``report.json``, ``report.md`` and ``model_augmented.json`` of a generic diagnosis in ``out``."""
    from rtlift.model.siso import save_siso_model

    with open(os.path.join(out, "report.json"), "w", encoding="utf-8") as f:
        json.dump(report, f, indent=1)
        f.write("\n")
    lines = ["# Diagnosis report", "", f"Scores: {report['scoring']}.", "",
             "| record | ρ before | ρ after | RMSE before | RMSE after |", "|---|---|---|---|---|"]
    for name, b in report["baseline"]["records"].items():
        a = report["augmented"]["records"][name]
        lines.append(f"| {name} | {b['corr']:.4f} | {a['corr']:.4f} | {b['rmse']:.5g} | {a['rmse']:.5g} |")
    lines += ["", "## Tried", ""] + [
        f"- **{e['name']}** ({e['kind']}, {'accepted' if e['accepted'] else 'not accepted'}): {e['evidence']}"
        for e in report["effects"]]
    lines += ["", "## Unexplained", ""] + ([f"- {u}" for u in report["unexplained"]] or ["- nothing"])
    with open(os.path.join(out, "report.md"), "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    save_siso_model(augmented, os.path.join(out, "model_augmented.json"))

"""What a single-input Wiener model lacks, from its residual; added with joint re-estimation.

Residual ε = y − ŷ (free run from rest, the first ``skip`` samples unscored) on the training
record, tested as in :mod:`rtlift.diagnose.residual`: whiteness, correlation with past input
(missed linear dynamics) and the Billings–Voon higher-order correlations with u² and ŷ² (a
missed nonlinear structure: the linear tests barely react while these do).

Candidate structure (kind ``structure``: the model's form is too simple, not a new event):

- ``output_dynamics`` — a linear block after the static map: Wiener becomes Wiener–Hammerstein.
  Not a block glued after the frozen Wiener fit: the whole model is re-identified from the
  best linear approximation, its poles and zeros split between G₁ and G₂, f and both blocks
  refined jointly (:func:`rtlift.sysid.identify.identify_siso`).
- ``nonlinear_feedback`` — the output fed back through a static map into the linear block's
  input (an amplitude-dependent resonance, Duffing-like), identified jointly from the ARX fit.

Of the candidates that pass, the one with the lower validation error is added.

It is accepted only if it lowers the pooled error on the validation records significantly
(:func:`rtlift.diagnose.selection.significant_gain`, the rule the lift diagnosis uses: ≥ 1.5 %
RMSE, Diebold–Mariano t ≥ 3 over blocks, no record worse by more than 1 %).
``saturation`` is named in INTERFACES.md but not built here yet.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import SisoRecord
from rtlift.diagnose.residual import higher_order, input_crosscorr, whiteness
from rtlift.diagnose.selection import DiagnoseOptions, significant_gain
from rtlift.sysid.identify import SisoOptions, identify_siso
from rtlift.sysid.model import SisoModel

HOW = {"output_dynamics": "Wiener-Hammerstein re-identified jointly from the best linear approximation's "
                          "pole/zero splits",
       "nonlinear_feedback": "the output fed back through k2 y^2 + k3 y^3 into a strictly proper linear "
                             "block, all refined jointly from the ARX fit"}


def _structure_params(model) -> dict[str, Any]:
    if model.structure == "nonlinear_feedback":
        return {"feedback": {"k2": float(model.k[0]), "k3": float(model.k[1])}, "order": model.n,
                "poles": [[float(p.real), float(p.imag)] for p in np.roots(np.concatenate([[1.0], model.a]))]}
    b2, a2 = model.g2.ba
    return {"poles": [[float(p.real), float(p.imag)] for p in np.roots(a2)],
            "zeros": [[float(z.real), float(z.imag)] for z in np.roots(b2)], "order": int(a2.size - 1)}


def predict(model: SisoModel, rec: SisoRecord) -> np.ndarray:
    """Free-run output over the record from rest; the model is left reset."""
    model.reset()
    out = model.simulate(rec.u)
    model.reset()
    return out


def record_scores(model: SisoModel, rec: SisoRecord, skip: int) -> dict[str, float]:
    """ρ, NRMSE, RMSE from sample ``skip`` on (``rtlift validate --skip``)."""
    return scores(rec.y[skip:], predict(model, rec)[skip:])


def diagnose_siso(model: SisoModel, train: SisoRecord, validate: list[SisoRecord],
                  skip: int = 0, options: SisoOptions | None = None) -> tuple[dict[str, Any], SisoModel]:
    """The report (INTERFACES.md schema) and the augmented model (module docstring)."""
    e = train.y - predict(model, train)
    s = max(skip, 1)
    tests = {"whiteness": whiteness(e[s:]), "input_crosscorr": input_crosscorr(e[s:], train.u[s:], label="u")}
    for t in higher_order(e[s:], train.u[s:], (train.y - e)[s:]):
        tests[t.name] = t
    evidence = "; ".join(f"{k} ({t.verdict}): {t.detail}" for k, t in tests.items()
                         if k in ("input_crosscorr", "bv_u2_e", "bv_y2_e"))
    # blocks for the significance test: about 40 over the validation data (the residual's
    # correlation time is the system's, unknown here; a lift record's 1 s blocks are 400 samples)
    block = max(50, sum(len(r) - skip for r in validate) // 40)
    before = [(r.y - predict(model, r))[skip:] for r in validate]
    rb = float(np.sqrt(np.mean(np.concatenate(before) ** 2)))
    effects = []
    augmented = model
    if model.structure == "wiener":
        measured = np.concatenate([r.y[skip:] for r in validate])
        tried = []
        for name, structure in (("output_dynamics", "wiener_hammerstein"), ("nonlinear_feedback",
                                                                            "nonlinear_feedback")):
            candidate = identify_siso(train, structure, options=options)
            after = [(r.y - predict(candidate, r))[skip:] for r in validate]
            ok, why = significant_gain(before, after, measured, block, DiagnoseOptions())
            ra = float(np.sqrt(np.mean(np.concatenate(after) ** 2)))
            tried.append((ok, ra, candidate))
            effects.append({"name": name, "kind": "structure", "accepted": False,
                            "params": _structure_params(candidate),
                            "evidence": f"{evidence}; {HOW[name]}; {why}",
                            "validation_rmse_before": rb, "validation_rmse_after": ra})
        admissible = [i for i, (ok, _, _) in enumerate(tried) if ok]
        if admissible:                                    # the better of the admissible structures
            k = min(admissible, key=lambda i: tried[i][1])
            effects[k]["accepted"] = True
            augmented = tried[k][2]
    unexplained = [f"{k}: {t.detail}" for k, t in tests.items() if t.significant] if augmented is model else []
    records = [train, *validate]
    report = {
        "version": 1,
        "baseline": {"records": {r.name: record_scores(model, r, skip) for r in records}},
        "augmented": {"records": {r.name: record_scores(augmented, r, skip) for r in records}},
        "effects": effects,
        "unexplained": unexplained,
        "scoring": f"free run from rest over whole records, the first {skip} samples unscored "
                   "(rtlift validate --skip)",
        "not_built": ["saturation"],
    }
    return report, augmented

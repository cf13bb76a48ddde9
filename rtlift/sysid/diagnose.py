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
  input (an amplitude-dependent resonance, Duffing-like), identified jointly from the ARX fit;
  with a Bouc–Wen hysteresis state in the map where that holds out better
  (:mod:`rtlift.sysid.feedback`).
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

Of the candidates that pass, the one with the lower validation error is added: the structures
are :class:`GenericCandidates`, walked by the one selection engine the lift diagnosis walks too
(:mod:`rtlift.diagnose.selection`): each tried structure a one-member combination, the admissible
one with the lowest pooled validation RMSE chosen, and the diagnosis a
:class:`~rtlift.diagnose.diagnosis.Diagnosis` that :func:`rtlift.diagnose.report.write` writes as
it writes a lift model's.

It is accepted only if it lowers the pooled error on the validation records significantly
(:func:`rtlift.diagnose.significance.significant_gain`, the rule the lift diagnosis uses: ≥ 1.5 %
RMSE, Diebold–Mariano t ≥ 3 over blocks, no record worse by more than 1 %).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import SisoRecord
from rtlift.core.threads import one_blas_thread
from rtlift.diagnose.diagnosis import DiagnoseOptions, Diagnosis, Trial
from rtlift.diagnose.selection import Node, Search, Selection, run
from rtlift.diagnose.significance import pooled_rmse
from rtlift.effects import STRUCTURES
from rtlift.model.siso import FeedbackModel, SaturatedModel, SisoModel, StoreChainModel
from rtlift.residual.stats import TestResult, higher_order, input_crosscorr, whiteness
from rtlift.sysid.common import NO_LIMITS, Limits, SisoOptions
from rtlift.sysid.identify import identify_siso
from rtlift.sysid.initial import initial_state
from rtlift.sysid.parallel import two_lanes

HOW = {e.name: e.how for e in STRUCTURES}
"""How each structure (:mod:`rtlift.effects`) is fitted, for the report."""
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
                **({"bouc_wen": dict(zip(("alpha", "g", "d"), model.hysteresis, strict=True)),
                    "substeps": model.substeps} if model.hysteretic else {}),
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


FINGERPRINT = ("none stored (a generic model file holds no fingerprint): the training residual's whiteness, its "
               "correlation with past input and the Billings-Voon correlations with u^2 and yhat^2 are tested "
               "against the 99 % bounds of a model that misses nothing")
"""The report's ``fingerprint``: what the generic residual tests compare with instead of one."""
FIT_TARGET = "each structure re-identified jointly on the training record's measured output"
RULE = ("the structure lowers the validation error significantly (the lift diagnosis's test); of those, "
        "the lowest pooled validation RMSE")


def residual_tests(model: SisoModel, rec: SisoRecord, start: int,
                   output: np.ndarray | None = None) -> dict[str, TestResult]:
    """The residual tests of ``model`` on ``rec`` from sample ``start`` on (module docstring);
    ``output``: its free run over the record, when already computed."""
    yhat = predict(model, rec) if output is None else output
    e, u, s = rec.y - yhat, rec.u, start
    most = max(1, (e.size - s) // 4)      # lags up to a quarter of the residual (the defaults from 320 samples on)
    tests = {"whiteness": whiteness(e[s:], min(40, most)),
             "input_crosscorr": input_crosscorr(e[s:], u[s:], min(80, most), label="u")}
    for t in higher_order(e[s:], u[s:], yhat[s:], min(40, most)):
        tests[t.name] = t
    return tests


def diagnose_siso(model: SisoModel, train: SisoRecord, validate: list[SisoRecord],
                  skip: int = 0, options: SisoOptions | None = None,
                  validate_skip: list[int] | None = None,
                  init_state: bool = False) -> tuple[dict[str, Any], SisoModel]:
    """The report (INTERFACES.md schema) and the augmented model of :func:`diagnose_generic`."""
    diag = diagnose_generic(model, train, validate, skip, options, validate_skip, init_state)
    return diag.report, diag.augmented


class GenericCandidates:
    """A generic model's structures as the engine's :class:`~rtlift.diagnose.selection.Candidates`
    (module docstring): each a whole model re-identified on the training record
    (:func:`rtlift.sysid.identify.identify_siso`), so one member per combination, every one
    fitted compared (no pool to screen), the lowest pooled validation RMSE among the admissible
    (no fingerprint: no level-free score, no confirmation bar, no evidence to rank by). The
    structures are independent fits, all made at the first :meth:`fit` on both cores
    (:func:`rtlift.sysid.parallel.two_lanes`: the serial results, bit for bit).
    ``validate_skip``: per validation record, the samples left unscored (default ``skip``; one
    long run's validation part is the whole run scored after its training part). ``init_state``:
    every model runs over a record from the state estimated on its unscored samples
    (:func:`rtlift.sysid.initial.initial_state`) instead of from rest."""

    name = "generic"
    screened = False
    max_members = 1
    parsimony = 0.0
    score = staticmethod(pooled_rmse)
    fingerprint = FINGERPRINT
    references = None                # no fingerprint to compare with
    fit_target = FIT_TARGET
    rule = RULE

    def __init__(self, model: SisoModel, train: SisoRecord, validate: list[SisoRecord], skip: int = 0,
                 options: SisoOptions | None = None, validate_skip: list[int] | None = None,
                 init_state: bool = False) -> None:
        self.base, self.train, self.validate, self.skip = model, train, validate, skip
        self.options = DiagnoseOptions()
        self.vskip = list(validate_skip) if validate_skip is not None else [skip] * len(validate)
        self.first = {r.name: k for r, k in zip(validate, self.vskip, strict=True)} if validate_skip is not None else {}
        self.unscored = {train.name: skip, **{r.name: k for r, k in zip(validate, self.vskip, strict=True)}}
        self.init_state = init_state
        self.start = max(skip, 1)
        self.outputs = {r.name: predict(model, r, self._init(r.name)) for r in (train, *validate)}
        self.tests = residual_tests(model, train, self.start, self.outputs[train.name])
        self.evidence_text = "; ".join(f"{k} ({t.verdict}): {t.detail}" for k, t in self.tests.items()
                                       if k in ("input_crosscorr", "bv_u2_e", "bv_y2_e"))
        # blocks for the significance test: about 40 over the validation data (the residual's
        # correlation time is the system's, unknown here; a lift record's 1 s blocks are 400 samples)
        self.block = max(50, sum(len(r) - k for r, k in zip(validate, self.vskip, strict=True)) // 40)
        self.measured = np.concatenate([r.y[k:] for r, k in zip(validate, self.vskip, strict=True)])
        self.tried = model.structure == "wiener" and not isinstance(model, SaturatedModel)
        self.limits, self.clip_evidence = clip_levels(train.y, train.y - self.outputs[train.name])
        self._fits = {}
        if self.tried:
            self._fits = {name: lambda structure=structure: identify_siso(train, structure, options=options)
                          for name, structure in FORMS}
            if self.limits != NO_LIMITS:
                self._fits[SATURATION.name] = lambda: _best_saturated(train, validate, self.vskip, options,
                                                                      self.limits, init_state)
        self.order = tuple(self._fits)
        self._fitted: dict[str, Any] | None = None
        self.not_built: list[str] = []   # none today: a limit on the input is the Wiener map's own saturation
        self.scoring = (f"free run over whole records from the state estimated on the first {skip} samples, "
                        "which are unscored (rtlift validate --skip --init-state)" if init_state else
                        f"free run from rest over whole records, the first {skip} samples unscored "
                        "(rtlift validate --skip)")

    def _init(self, name: str) -> int:
        return self.unscored[name] if self.init_state else 0

    # ------------------------------------------------------------------ the engine's questions
    def errors(self, model: SisoModel) -> list[np.ndarray]:
        return [(r.y - predict(model, r, self._init(r.name)))[k:] for r, k in zip(self.validate, self.vskip,
                                                                                   strict=True)]

    def fit(self, name: str, parent: Node, search: Search) -> tuple[SisoModel, SisoModel] | str:
        """The structure re-identified whole (``parent`` is the model: one member each); a
        structure the data cannot be fitted in says why, not fatal."""
        if self._fitted is None:            # every structure is fitted alone (step 1): all at once, both cores
            self._fitted = dict(zip(self._fits, two_lanes(list(self._fits.values())), strict=True))
        model = self._fitted[name]
        if isinstance(model, ValueError):
            return str(model)
        if isinstance(model, Exception):
            raise model
        return model, model

    def excludes(self, name: str) -> tuple[str, ...]:
        return ()

    def n_params(self, node: Node) -> None:
        return None                      # a structure's parameters are not counted

    def on_bound(self, node: Node) -> str:
        return ""

    def evidence(self, name: str, node: Node, search: Search) -> None:
        return None

    def confirmed(self, node: Node, name: str, search: Search) -> bool:
        return False

    def rank(self, node: Node, near: list[Node], search: Search) -> tuple:
        return ()

    def row_why(self, verdicts: list[tuple[str, bool, str]]) -> str:
        return verdicts[0][2]            # one member: its own verdict

    # ------------------------------------------------------------------ what the report says
    def trials(self, sel: Selection) -> list[Trial]:
        rb = sel.judge.pooled(sel.base.errors)
        trials: list[Trial] = []
        for name in self.order:
            s = sel.singles[name]
            if s.node.failed:
                trials.append(Trial(name, False, {}, f"not fitted: {s.why}", rb, rb, "structure", "not fitted"))
                continue
            candidate = s.node.model
            trials.append(Trial(name, name in sel.best.members, _structure_params(candidate),
                                f"{self.clip_evidence}; {HOW[name]} (best form: {candidate.structure}, "
                                f"limit on the {candidate.limits()['where']}); {s.why}"
                                if name == SATURATION.name else f"{self.evidence_text}; {HOW[name]}; {s.why}",
                                rb, sel.judge.pooled(s.node.errors), "structure", s.why))
        if self.tried and self.limits == NO_LIMITS:
            trials.append(Trial(SATURATION.name, False, {"lower": None, "upper": None, "where": "output"},
                                f"not tried: no clipping level ({self.clip_evidence})", rb, rb, "structure"))
        return trials

    def refine(self, sel: Selection) -> tuple[SisoModel, None]:
        return sel.best.model, None      # each structure is re-identified whole

    def unexplained(self, sel: Selection, trials: list[Trial]) -> list[str]:
        if sel.best.model is not self.base:
            return []
        return [f"{k}: {t.detail}" for k, t in self.tests.items() if t.significant]

    def evaluate(self, model: SisoModel) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray],
                                                  dict[str, dict[str, TestResult]]]:
        """Per record: :func:`record_scores`' numbers (from its unscored samples on), the residual
        from its first scored sample (0 but for a run's validation part), the residual tests."""
        recs = [self.train, *self.validate]
        out = self.outputs if model is self.base else {r.name: predict(model, r, self._init(r.name)) for r in recs}
        first = {r.name: self.first.get(r.name, 0) for r in recs}
        return ({r.name: scores(r.y[self.unscored[r.name]:], out[r.name][self.unscored[r.name]:]) for r in recs},
                {r.name: (r.y - out[r.name])[first[r.name]:] for r in recs},
                {r.name: residual_tests(model, r, max(self.start, first[r.name]), out[r.name]) for r in recs})


@one_blas_thread
def diagnose_generic(model: SisoModel, train: SisoRecord, validate: list[SisoRecord],
                     skip: int = 0, options: SisoOptions | None = None,
                     validate_skip: list[int] | None = None, init_state: bool = False) -> Diagnosis:
    """The diagnosis (module docstring) of :class:`GenericCandidates`, walked by the engine
    (:func:`rtlift.diagnose.selection.run`), as :func:`rtlift.diagnose.report.write` writes it."""
    return run(GenericCandidates(model, train, validate, skip, options, validate_skip, init_state))


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
    if best is None:
        raise ValueError("no form with the limit in place could be fitted")
    return best[1]

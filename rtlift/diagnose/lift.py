"""A lift model's candidates for the selection engine (:mod:`rtlift.diagnose.selection`): the
effects of :mod:`rtlift.effects`, residual tests → candidate effects → model selection on
held-out records.

0. **Reference.** The training record is compared with the fingerprint entry its *input*
   points at (:func:`.fingerprint.reference`): an identification run it repeats bit for bit, else
   one whose input descriptor it matches, else the print predicted for its input (the model's own
   misfit carried over from the campaign, :mod:`rtlift.residual.misfit`). Its name plays no part.
1. **Candidates.** Every effect of the catalog is fitted alone on the training record, to its
   residual — except an effect that replaces the model's static map (hysteresis, an output
   nonlinearity: ``Effect.fits_change``) where the model's own misfit on the record's input is
   known (:func:`.fingerprint.change_misfit`): it is fitted to what changed since identification,
   ΔCL minus that misfit — the identification run's own where the record repeats one (the best
   case), else the misfit predicted for its input where the campaign says it carries to other
   inputs (λ > 0). That target is free of the model's systematic
   misfit, itself a misfit of the map that a map-shaped effect would absorb, but carries the
   noise of both runs, which costs more than it gains for a slow additive or linear effect
   (fitted so everywhere, a fade took a drift's place on the independent plant). The residual
   tests and the fingerprint comparison use the record as measured.
2. **Pool**, 3. **combinations** in the catalog's order (the signal path's), each effect fitted
   on the model with the ones before it, and 4. **every member earns its place**: the engine's
   (:mod:`rtlift.diagnose.selection`), a lift model screening its pool (the effects stack) and
   combining up to ``max_effects``, the significance test over 1 s blocks. A member whose own
   evidence departs from the fingerprint (step 5) is confirmed at ``min_t_confirm``. Among the
   admissible combinations (the empty one included) within ``parsimony`` of the lowest
   *level-free* validation RMSE (each record's own mean error taken out,
   :func:`~rtlift.diagnose.significance.level_free_rmse`), the one with the suspect wins where
   one is named (step 5), then the one the others cannot replace (an encompassing test on the
   held-out records, :meth:`.selection.Judge.encompassing`), then the one ranked first by step 5,
   then the one with fewer parameters. Why level-free:
   the model's own level misfit differs between record types and is unknown on a type the
   campaign lacks, and an effect that shifts the lift can win on it without being there. The
   paper's hybrid on the independent plant: clean mean residual +0.0025 on ``random``, −0.0057
   and −0.0108 on the two sines; with ``random`` training, a fade (lowering the lift in
   proportion) beat the true drift on the sines' raw error, 0.01301 against 0.01356, and loses
   with the means out, 0.00897 against 0.00858. Admissibility stays on the raw error.
5. **Effect or structure.** Each chosen member's evidence is recomputed on the residual of the
   combination without it and compared with the fingerprint (:mod:`rtlift.residual.fingerprint`). It is an
   ``effect`` (something changed since identification) when its own evidence departs, or when
   the model's error level on the training record departs from the one it had on that record
   type at identification and this member lowers it by as much again (a z of the excess that
   falls by ``Z_DEPART`` or more); otherwise the model already
   lacked it on its own campaign, and it is ``structure``. Between near-equal combinations
   (step 4) the one with the *suspect* wins first where another source of evidence names one
   (``DiagnoseOptions.suspect``, ``rtlift diagnose --suspect``: under ``--adapt`` the live monitor's
   departure, raised against the model's own null in time — quiet before, departed now — which a
   window alone cannot give), then the one with more effects, then the one whose members' own
   evidence is stronger (Σ|z|): two explanations that fit alike are told apart by what points at
   them. On a closed loop's 26-s window after a 70 % fade (tests/data/adapt_fade_window.csv) a fade
   and a zero drift fit alike (validation RMSE 0.00872 both, level-free 0.00787 and 0.00784): the
   encompassing test and the drift's own evidence (z −2.6 against +0.5) chose the drift, and that
   run's adaptation swapped in a drift; the monitor's ``hold`` test had named the fade, which the
   window's data cannot tell from the drift.

6. **Re-estimation.** With the chosen effects in, φ and the Wiener part's scale are
   re-estimated jointly on the training record (:func:`rtlift.effects.surgery.reestimate`), kept only if
   the validation error is lower and no record worse by more than 1 %.

Scores everywhere are :func:`rtlift.model.validation.predict_record` over whole records: the
report's numbers are the ones ``rtlift validate`` prints for the same model file.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import Record
from rtlift.core.threads import one_blas_thread
from rtlift.diagnose.diagnosis import DiagnoseOptions, Diagnosis, Trial
from rtlift.diagnose.selection import Errors, Node, Search, Selection, Single, run
from rtlift.diagnose.significance import level_free_rmse
from rtlift.diagnose.unexplained import unexplained
from rtlift.effects import BY_NAME as EFFECTS
from rtlift.effects import EFFECT_NAMES, Context, Fitted, predict, reestimate
from rtlift.effects.zero_drift import ZeroDriftEffect
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import (
    FINGERPRINT_START_S,
    Z_DEPART,
    Departure,
    change_misfit,
    error_departure,
    input_lines_hz,
    record_tests,
    reference,
)
from rtlift.residual.stats import TestResult

SCORING = ("whole records from rest (rtlift validate's numbers); a periodic_disturbance's "
           "line phases are estimated on each record itself, as rtlift validate does")


@dataclass(frozen=True)
class _Kind:
    is_effect: bool
    specific: Departure
    text: str


class LiftCandidates:
    """A lift model's effects as the engine's :class:`~rtlift.diagnose.selection.Candidates`
    (module docstring): each fitted on the model with the ones before it
    (:meth:`rtlift.effects.base.Effect.fit`), to the training residual or to what changed since
    identification (step 1); evidence against the model's fingerprint."""

    name = "lift"
    screened = True
    score = staticmethod(level_free_rmse)
    not_built = None                 # every lift effect is in the catalog
    scoring = SCORING

    def __init__(self, model: HybridModel, train: Record, validate: list[Record],
                 options: DiagnoseOptions | None = None, score_from: list[int] | None = None) -> None:
        self.options = opt = options or DiagnoseOptions()
        fs = model.fs_hz
        self.base, self.train, self.validate = model, train, validate
        self.start = int(round(float(model.fingerprint.get("start", FINGERPRINT_START_S * fs))))
        self.score_from = list(score_from) if score_from is not None else [0] * len(validate)
        self.first = {r.name: k for r, k in zip(validate, self.score_from, strict=True)}
        ref = reference(model.fingerprint, model, train, self.start)
        self.fp, self.fingerprint = ref.entry, ref.text
        misfit, self.fit_target = change_misfit(model.fingerprint, model, train, ref)
        self.target = train if misfit is None else dataclasses.replace(train, dcl=train.dcl - misfit)
        self.references = {train.name: ref.to_dict(),
                           **{r.name: reference(model.fingerprint, model, r, self.start).to_dict()
                              for r in validate}}
        self.order = EFFECT_NAMES
        self.max_members, self.parsimony = opt.max_effects, opt.parsimony
        self.block = int(fs)
        self.measured = np.concatenate([r.dcl[k:] for r, k in zip(validate, self.score_from, strict=True)])
        self.lines = input_lines_hz(train)
        self.rule = ("every member lowers the validation error significantly; within "
                     f"{100 * opt.parsimony:g} % of the lowest level-free validation RMSE (each "
                     "record's mean error taken out), "
                     + ("" if opt.suspect is None else f"the one with the suspect named beside the record "
                        f"({opt.suspect}), then ")
                     + "the most members whose evidence departs from the fingerprint, then the fewest parameters")
        self._tests: dict[tuple[str, ...], dict[str, TestResult]] = {}

    # ------------------------------------------------------------------ the engine's questions
    def errors(self, model: HybridModel) -> Errors:
        return [(r.dcl - predict(model, r).total)[k:] for r, k in zip(self.validate, self.score_from, strict=True)]

    def fit(self, name: str, parent: Node, search: Search) -> tuple[Fitted, HybridModel] | str:
        """``name`` fitted on ``parent``'s model: to what changed since identification for an effect
        that replaces the static map (``Effect.fits_change``) where the record repeats an
        identification experiment, to the training residual otherwise (module docstring, 1)."""
        ctx = self.context(parent.members, search)
        change = EFFECTS[name].fits_change and self.target is not self.train
        fitted = EFFECTS[name].fit(parent.model, self.target if change else self.train, ctx)
        if not isinstance(fitted, Fitted):
            return fitted
        if change:
            fitted = dataclasses.replace(fitted, note="; ".join(
                n for n in (fitted.note, "fitted to what changed since identification") if n))
        return fitted, fitted.model

    def excludes(self, name: str) -> tuple[str, ...]:
        return EFFECTS[name].excludes

    def n_params(self, node: Node) -> int:
        return sum(EFFECTS[n].n_params(node.fits[n].params) for n in node.members)

    def on_bound(self, node: Node) -> str:
        return "; ".join(f"{n}: {node.fits[n].on_bound}" for n in node.members if node.fits[n].on_bound)

    def evidence(self, name: str, node: Node, search: Search) -> Departure:
        return EFFECTS[name].evidence(self.tests((), search), self.fp, node.fits[name])

    def confirmed(self, node: Node, name: str, search: Search) -> bool:
        return self.classify(node, name, search).specific.departs

    def rank(self, node: Node, near: list[Node], search: Search) -> tuple:
        """The one with the suspect (``options.suspect``), the one the others cannot replace, the most
        effects, the strongest own evidence, the fewest parameters (module docstring, 4–5)."""
        kinds = [self.classify(node, m, search) for m in node.members]
        return (-(self.options.suspect in node.members), -search.judge.encompassing(node, near, search),
                -sum(k.is_effect for k in kinds),
                -sum(min(abs(k.specific.z), 50.0) for k in kinds), self.n_params(node))

    def row_why(self, verdicts: list[tuple[str, bool, str]]) -> str:
        lacking = [f"{m} ({why})" for m, ok, why in verdicts if not ok]
        return ("every member lowers the error significantly" if not lacking else
                "does not earn its place: " + "; ".join(lacking))

    # ------------------------------------------------------------------ the lift model's own
    def tests(self, members: tuple[str, ...], search: Search) -> dict[str, TestResult]:
        if members not in self._tests:
            self._tests[members] = record_tests(search.node(members).model, self.train, self.start)[0]
        return self._tests[members]

    def context(self, members: tuple[str, ...], search: Search) -> Context:
        return Context(self.train.fs_hz, self.start, self.tests(members, search), self.fp, self.lines)

    def level(self, members: tuple[str, ...], search: Search) -> Departure | None:
        """The training residual's error level against the print (None without a print)."""
        if self.fp is None:
            return None
        e = self.train.dcl - predict(search.node(members).model, self.train).total
        return error_departure(e[self.start:], self.fp, self.train.fs_hz)

    def classify(self, node: Node, name: str, search: Search) -> _Kind:
        """Effect or structure for member ``name`` of ``node`` (module docstring, 5)."""
        rest = search.without(node.members, name)
        specific = EFFECTS[name].evidence(self.tests(rest.members, search), self.fp, node.fits[name])
        before, after = self.level(rest.members, search), self.level(node.members, search)
        restores = before is not None and before.departs and before.z - after.z >= Z_DEPART
        if specific.departs:
            text = f"{specific.text}: departs from the fingerprint"
        elif restores:
            text = (f"{specific.text}; the model's error on this record type grew since identification "
                    f"({before.text}) and this takes a significant part of the growth away ({after.text})")
        else:
            text = f"{specific.text}: within the fingerprint" + (f"; {after.text}" if after else "")
        return _Kind(specific.departs or restores, specific, text)

    # ------------------------------------------------------------------ what the report says
    def trials(self, sel: Selection) -> list[Trial]:
        """Every effect of the catalog as reported (module docstring, 5)."""
        search, judge, best, opt = sel.search, sel.judge, sel.best, self.options
        rb = judge.pooled(sel.base.errors)
        trials: list[Trial] = []
        for name in self.order:
            s = sel.singles[name]
            if name in best.members:
                rest = search.without(best.members, name)
                fitted = best.fits[name]
                verdict = self.classify(best, name, search)
                _, why_in = search.earns(best, name, opt)
                kind = "effect" if verdict.is_effect else "structure"
                text = f"{verdict.text}; {why_in}" + (f"; {fitted.note}" if fitted.note else "")
                trials.append(Trial(name, True, fitted.params, text, judge.pooled(rest.errors),
                                    judge.pooled(best.errors), kind, why_in))
                continue
            if s.evidence is None:
                trials.append(Trial(name, False, {}, f"not fitted: {s.why}", rb, rb, "effect", s.why))
                continue
            fitted, dep = s.node.fits[name], s.evidence
            kind = "effect" if dep.departs else "structure"
            bound = self.on_bound(s.node)
            reason = (f"ended on a bound: {bound}" if bound else
                      "not in the chosen combination" if name in sel.pool else
                      "neither lowers the validation error significantly nor departs from the fingerprint"
                      if not dep.departs else "does not lower the validation error significantly")
            trials.append(Trial(name, False, fitted.params, f"{dep.text}; {s.why}; {reason}", rb,
                                judge.pooled(s.node.errors), kind, s.why))
        return trials

    def refine(self, sel: Selection) -> tuple[HybridModel, dict[str, Any]]:
        """φ and the Wiener scale re-estimated with the chosen effects in (module docstring, 6)."""
        best, judge = sel.best, sel.judge
        refit: dict[str, Any] = {"tried": bool(best.members)}
        if not best.members:
            return best.model, refit
        again, scales = reestimate(best.model, self.train, self.start)
        after = judge.errors(again)
        ok, why = judge.verdict(best.errors, after, DiagnoseOptions(min_gain=0.0, min_t=0.0))
        better = ok and judge.pooled(after) < judge.pooled(best.errors)
        refit.update(scales, kept=better, why=why)
        return (again if better else best.model), refit

    def unexplained(self, sel: Selection, trials: list[Trial]) -> list[str]:
        return unexplained(self.tests(sel.best.members, sel.search), self.fp, trials,
                           (len(self.train) - self.start) / self.train.fs_hz,
                           drift_holds=_holds_out(sel.singles[ZeroDriftEffect.name], sel, self.options))

    def evaluate(self, model: HybridModel) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray],
                                                    dict[str, dict[str, TestResult]]]:
        """Per record: scores, residual and tests from its first scored sample (0 but for the
        validation part of a run)."""
        recs = [self.train, *self.validate]
        first = {r.name: self.first.get(r.name, 0) for r in recs}
        tests = {r.name: record_tests(model, r, max(self.start, first[r.name]))[0] for r in recs}
        resid = {r.name: (r.dcl - predict(model, r).total)[first[r.name]:] for r in recs}
        measured = {r.name: r.dcl[first[r.name]:] for r in recs}
        return {n: scores(z, z - resid[n]) for n, z in measured.items()}, resid, tests


def _holds_out(single: Single, sel: Selection, opt: DiagnoseOptions) -> bool:
    """Does a candidate fitted alone lower the held-out error at the bar a member with departing
    evidence needs (t ≥ ``min_t_confirm``)?"""
    if single.evidence is None or single.node.failed:
        return False
    return sel.judge.verdict(sel.base.errors, single.node.errors,
                             dataclasses.replace(opt, min_t=opt.min_t_confirm))[0]


@one_blas_thread
def diagnose(model: HybridModel, train: Record, validate: list[Record],
             options: DiagnoseOptions | None = None, score_from: list[int] | None = None) -> Diagnosis:
    """The lift model's diagnosis (module docstring), walked by the engine
    (:func:`rtlift.diagnose.selection.run`).

    ``score_from`` (one per validation record, default 0): the samples before it are run
    through from rest but not scored nor tested — the validation part of one long run is the
    whole run scored after its training part, so the model's state (a fade's accumulated
    on-time, a drift's clock, the slow states) at the split is the one the run led to."""
    return run(LiftCandidates(model, train, validate, options, score_from))

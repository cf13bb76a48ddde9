"""Closing the loop: residual tests → candidate effects → model selection on held-out records.

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
2. **Pool.** A candidate enters the pool when its fit is interior (no parameter on a bound of
   its range: a fade to 0, a "mode" damped like a lag) and it either lowers the validation
   error or its evidence departs from the fingerprint; then each other candidate fitted beside
   the best of them that lowers the validation error further (a strong effect can hide a weak
   one from a fit on the baseline); at most ``pool_size``, best first.
3. **Combinations** of up to ``max_effects`` pool members (exclusive pairs left out) are built
   in the catalog's order, each member fitted on the model with the ones before it, and scored
   on the validation records, which no fit ever sees.
4. **Every member earns its place.** A combination is admissible only if removing any one
   member makes the validation error significantly worse (:meth:`_Judge.verdict`: relative
   RMSE gain ≥ ``min_gain``, a Diebold–Mariano t ≥ ``min_t`` over 1 s blocks, no record worse
   by more than 1 %, ρ not lower by more than 0.005). A member whose own evidence departs from
   the fingerprint (step 5) needs t ≥ ``min_t_confirm`` only: the training record formed the
   hypothesis, independently of the held-out records, which then confirm it; a member without
   such evidence is a search over the catalog and needs the stricter ``min_t``
   (:meth:`_Search.earns`). Among the admissible combinations (the
   empty one included) within ``parsimony`` of the lowest *level-free* validation RMSE (each
   record's own mean error taken out, :meth:`_Judge.level_free`), the one the others cannot
   replace wins (an encompassing test on the held-out records, :meth:`_Judge.encompassing`),
   then the one ranked first by step 5, then the one with fewer parameters. Why level-free:
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
   (step 4) the one with more effects wins, then the one whose members' own evidence is
   stronger (Σ|z|): two explanations that fit alike are told apart by what points at them.

6. **Re-estimation.** With the chosen effects in, φ and the Wiener part's scale are
   re-estimated jointly on the training record (:func:`rtlift.effects.surgery.reestimate`), kept only if
   the validation error is lower and no record worse by more than 1 %.

Scores everywhere are :func:`rtlift.model.validation.predict_record` over whole records: the
report's numbers are the ones ``rtlift validate`` prints for the same model file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.core.records import Record
from rtlift.core.threads import one_blas_thread
from rtlift.diagnose.diagnosis import DiagnoseOptions, Diagnosis, Trial, report_dict
from rtlift.diagnose.significance import combination, level_free_rmse, pooled_rmse, significant_gain
from rtlift.diagnose.unexplained import unexplained
from rtlift.effects import BY_NAME as EFFECTS
from rtlift.effects import CATALOG, EFFECT_NAMES, Context, Fitted, predict, reestimate
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
from rtlift.residual.stats import TestResult, cluster_ols


class _Judge:
    """Scores models on the validation records (:func:`predict` over whole records from rest,
    each scored from its ``score_from`` sample on: 0 for a record of its own)."""

    def __init__(self, records: list[Record], fs: float, score_from: list[int]) -> None:
        self.records, self.block, self.score_from = records, int(fs), score_from
        self._meas = np.concatenate([r.dcl[k:] for r, k in zip(records, score_from, strict=True)])

    def errors(self, model: HybridModel) -> list[np.ndarray]:
        return [(r.dcl - predict(model, r).total)[k:] for r, k in zip(self.records, self.score_from, strict=True)]

    pooled = staticmethod(pooled_rmse)
    level_free = staticmethod(level_free_rmse)

    def encompassing(self, node: _Node, rivals: list[_Node], search: _Search) -> float:
        """How well ``node`` holds against each rival that is not nested in it or around it
        (Davidson & MacKinnon's J test, 1981, on the held-out records): with c_A, c_B the two
        combinations' corrections to what they share, z − ŷ_shared ≈ α c_A + β c_B by least
        squares (cluster-robust over 1 s blocks); the t of α. Returns the smallest over the
        rivals (inf without one): two explanations that fit alike are told apart by which of
        them the other cannot replace."""
        worst = math.inf
        mine = set(node.members)
        for other in rivals:
            theirs = set(other.members)
            if mine <= theirs or theirs <= mine:
                continue
            shared = search.node(_ordered(mine & theirs))
            e = np.concatenate(shared.errors)            # z − ŷ_shared
            c_a = e - np.concatenate(node.errors)         # ŷ_A − ŷ_shared
            c_b = e - np.concatenate(other.errors)
            beta, se = cluster_ols(np.column_stack([c_a, c_b]), e, self.block)
            worst = min(worst, float(beta[0] / se[0]))
        return worst

    def verdict(self, before: list[np.ndarray], after: list[np.ndarray], opt: DiagnoseOptions) -> tuple[bool, str]:
        """Is ``after`` significantly better than ``before`` on every count (module doc, 4)?"""
        return significant_gain(before, after, self._meas, self.block, opt)


@dataclass
class _Node:
    """A combination: its members in catalog order, their fits, the model and its errors."""

    members: tuple[str, ...]
    fits: dict[str, Fitted]
    model: HybridModel
    errors: list[np.ndarray]
    failed: str = ""                     # why a member could not be fitted here

    @property
    def n_params(self) -> int:
        return sum(EFFECTS[n].n_params(self.fits[n].params) for n in self.members)

    @property
    def on_bound(self) -> str:
        return "; ".join(f"{n}: {self.fits[n].on_bound}" for n in self.members if self.fits[n].on_bound)


@dataclass(frozen=True)
class _Kind:
    is_effect: bool
    specific: Departure
    text: str


class _Search:
    """Fits combinations by extending their prefixes (each fitted once, cached)."""

    def __init__(self, base: HybridModel, train: Record, judge: _Judge, start: int,
                 fp: dict[str, Any] | None, target: Record | None = None) -> None:
        self.train, self.judge, self.start, self.fp = train, judge, start, fp
        self.target = target or train          # what the fits explain (module docstring, 1)
        self.lines = input_lines_hz(train)
        self.nodes: dict[tuple[str, ...], _Node] = {(): _Node((), {}, base, judge.errors(base))}
        self._tests: dict[tuple[str, ...], dict[str, TestResult]] = {}

    def tests(self, members: tuple[str, ...]) -> dict[str, TestResult]:
        if members not in self._tests:
            self._tests[members] = record_tests(self.node(members).model, self.train, self.start)[0]
        return self._tests[members]

    def context(self, members: tuple[str, ...]) -> Context:
        return Context(self.train.fs_hz, self.start, self.tests(members), self.fp, self.lines)

    def node(self, members: tuple[str, ...]) -> _Node:
        if members in self.nodes:
            return self.nodes[members]
        parent = self.node(members[:-1])
        name = members[-1]
        if parent.failed:
            node = _Node(members, parent.fits, parent.model, parent.errors, parent.failed)
        else:
            fitted = self._fit(name, parent.model, self.context(members[:-1]))
            if isinstance(fitted, tuple):
                node = _Node(members, {**parent.fits, name: fitted[0]}, fitted[0].model, fitted[1])
            else:
                node = _Node(members, parent.fits, parent.model, parent.errors, f"{name}: {fitted}")
        self.nodes[members] = node
        return node

    def _fit(self, name: str, model: HybridModel, ctx: Context) -> tuple[Fitted, list[np.ndarray]] | str:
        """``name`` fitted on ``model``: to what changed since identification for an effect that
        replaces the static map (``Effect.fits_change``) where the record repeats an identification
        experiment, to the training residual otherwise (module docstring, 1); with its errors on
        the validation records."""
        change = EFFECTS[name].fits_change and self.target is not self.train
        fitted = EFFECTS[name].fit(model, self.target if change else self.train, ctx)
        if not isinstance(fitted, Fitted):
            return fitted
        if change:
            fitted = dataclasses.replace(fitted, note="; ".join(
                n for n in (fitted.note, "fitted to what changed since identification") if n))
        return fitted, self.judge.errors(fitted.model)

    def earns(self, node: _Node, name: str, opt: DiagnoseOptions) -> tuple[bool, str]:
        """Does member ``name`` earn its place in ``node`` (module docstring, 4)? Its removal must
        make the validation error significantly worse: t ≥ ``opt.min_t``, or t ≥
        ``opt.min_t_confirm`` where its own evidence on the training record departs from the
        fingerprint (the held-out records then confirm a hypothesis the training record formed)."""
        before = self.without(node.members, name).errors
        ok, why = self.judge.verdict(before, node.errors, opt)
        if ok or opt.min_t_confirm >= opt.min_t or not self.classify(node, name).specific.departs:
            return ok, why
        ok, why = self.judge.verdict(before, node.errors, dataclasses.replace(opt, min_t=opt.min_t_confirm))
        return ok, f"{why} (its evidence departs from the fingerprint: t >= {opt.min_t_confirm:g} confirms it)"

    def without(self, members: tuple[str, ...], name: str) -> _Node:
        return self.node(tuple(m for m in members if m != name))

    def level(self, members: tuple[str, ...]) -> Departure | None:
        """The training residual's error level against the print (None without a print)."""
        if self.fp is None:
            return None
        e = self.train.dcl - predict(self.node(members).model, self.train).total
        return error_departure(e[self.start:], self.fp, self.train.fs_hz)

    def classify(self, node: _Node, name: str) -> _Kind:
        """Effect or structure for member ``name`` of ``node`` (module docstring, 5)."""
        rest = self.without(node.members, name)
        specific = EFFECTS[name].evidence(self.tests(rest.members), self.fp, node.fits[name])
        before, after = self.level(rest.members), self.level(node.members)
        restores = before is not None and before.departs and before.z - after.z >= Z_DEPART
        if specific.departs:
            text = f"{specific.text}: departs from the fingerprint"
        elif restores:
            text = (f"{specific.text}; the model's error on this record type grew since identification "
                    f"({before.text}) and this takes a significant part of the growth away ({after.text})")
        else:
            text = f"{specific.text}: within the fingerprint" + (f"; {after.text}" if after else "")
        return _Kind(specific.departs or restores, specific, text)


def _ordered(names) -> tuple[str, ...]:
    return tuple(n for n in EFFECT_NAMES if n in set(names))


def _compatible(names: tuple[str, ...]) -> bool:
    return not any(x in EFFECTS[n].excludes for n in names for x in names)


@one_blas_thread
def diagnose(model: HybridModel, train: Record, validate: list[Record],
             options: DiagnoseOptions | None = None, score_from: list[int] | None = None) -> Diagnosis:
    """Candidates, combinations, selection and classification (module docstring).

    ``score_from`` (one per validation record, default 0): the samples before it are run
    through from rest but not scored nor tested — the validation part of one long run is the
    whole run scored after its training part, so the model's state (a fade's accumulated
    on-time, a drift's clock, the slow states) at the split is the one the run led to."""
    opt = options or DiagnoseOptions()
    fs = model.fs_hz
    start = int(round(float(model.fingerprint.get("start", FINGERPRINT_START_S * fs))))
    score_from = list(score_from) if score_from is not None else [0] * len(validate)
    first = {r.name: k for r, k in zip(validate, score_from, strict=True)}
    ref = reference(model.fingerprint, model, train, start)
    fp, fp_note = ref.entry, ref.text
    misfit, target_note = change_misfit(model.fingerprint, model, train, ref)
    target = train if misfit is None else dataclasses.replace(train, dcl=train.dcl - misfit)
    judge = _Judge(validate, fs, score_from)
    search = _Search(model, train, judge, start, fp, target)
    base = search.node(())
    rb = judge.pooled(base.errors)
    tests_base = search.tests(())

    # 1-2: candidates alone, and the pool
    singles: dict[str, tuple[_Node, Departure | None, bool, str]] = {}
    for eff in CATALOG:
        node = search.node((eff.name,))
        if node.failed:
            singles[eff.name] = (node, None, False, node.failed.split(": ", 1)[1])
            continue
        dep = eff.evidence(tests_base, fp, node.fits[eff.name])
        ok, why = judge.verdict(base.errors, node.errors, opt)
        singles[eff.name] = (node, dep, ok, why)
    pool = [n for n, (node, dep, ok, _) in singles.items()
            if dep is not None and not node.on_bound and (ok or dep.departs)
            and judge.pooled(node.errors) < rb]
    pool = sorted(pool, key=lambda n: judge.pooled(singles[n][0].errors))[:opt.pool_size]
    if pool:     # forward screening: a strong effect can hide a weak one from a fit on the baseline
        lead = pool[0]
        for eff in CATALOG:
            if eff.name in pool or not _compatible((lead, eff.name)) or len(pool) >= opt.pool_size:
                continue
            pair = search.node(_ordered((lead, eff.name)))
            if pair.failed or pair.on_bound:
                continue
            ok, _ = judge.verdict(singles[lead][0].errors, pair.errors, opt)
            if ok:
                pool.append(eff.name)

    # 3-4: combinations, admissibility, choice
    table = []
    best: _Node = base
    admissible_nodes = [base]
    for size in range(1, min(opt.max_effects, len(pool)) + 1):
        for combo in combinations(_ordered(pool), size):
            if not _compatible(combo):
                continue
            node = search.node(combo)
            count = node.n_params if not node.failed else None
            if node.failed:
                row = combination(combo, node.errors, count, False, f"not fitted: {node.failed}")
            elif node.on_bound:
                row = combination(combo, node.errors, count, False, f"on a bound: {node.on_bound}")
            else:
                weak = [(m, search.earns(node, m, opt)) for m in combo]
                lacking = [f"{m} ({why})" for m, (ok, why) in weak if not ok]
                row = combination(combo, node.errors, count, not lacking,
                                  "every member lowers the error significantly" if not lacking else
                                  "does not earn its place: " + "; ".join(lacking))
                if not lacking:
                    admissible_nodes.append(node)
            table.append(row)
    level_free = {n.members: judge.level_free(n.errors) for n in admissible_nodes}
    lowest = min(level_free.values())
    near = [n for n in admissible_nodes if level_free[n.members] <= lowest * (1 + opt.parsimony)]

    def rank(node: _Node) -> tuple:
        kinds = [search.classify(node, m) for m in node.members]
        return (-judge.encompassing(node, near, search), -sum(k.is_effect for k in kinds),
                -sum(min(abs(k.specific.z), 50.0) for k in kinds), node.n_params, level_free[node.members])
    best = min(near, key=rank)

    # 5: effect or structure, and the trials as reported
    trials: list[Trial] = []
    for eff in CATALOG:
        node, dep, ok, why = singles[eff.name]
        if eff.name in best.members:
            rest = search.without(best.members, eff.name)
            fitted = best.fits[eff.name]
            verdict = search.classify(best, eff.name)
            _, why_in = search.earns(best, eff.name, opt)
            kind = "effect" if verdict.is_effect else "structure"
            text = f"{verdict.text}; {why_in}" + (f"; {fitted.note}" if fitted.note else "")
            trials.append(Trial(eff.name, True, fitted.params, text, judge.pooled(rest.errors),
                                judge.pooled(best.errors), kind, why_in))
            continue
        if dep is None:
            trials.append(Trial(eff.name, False, {}, f"not fitted: {why}", rb, rb, "effect", why))
            continue
        fitted = node.fits[eff.name]
        kind = "effect" if dep.departs else "structure"
        reason = (f"ended on a bound: {node.on_bound}" if node.on_bound else
                  "not in the chosen combination" if eff.name in pool else
                  "neither lowers the validation error significantly nor departs from the fingerprint"
                  if not dep.departs else "does not lower the validation error significantly")
        trials.append(Trial(eff.name, False, fitted.params, f"{dep.text}; {why}; {reason}", rb,
                            judge.pooled(node.errors), kind, why))

    records = [train, *validate]
    augmented = best.model
    refit = {"tried": bool(best.members)}
    if best.members:          # 6: what the effects interact with, re-estimated with them in
        again, scales = reestimate(best.model, train, start)
        after = judge.errors(again)
        ok, why = judge.verdict(best.errors, after, DiagnoseOptions(min_gain=0.0, min_t=0.0))
        better = ok and judge.pooled(after) < judge.pooled(best.errors)
        refit.update(scales, kept=better, why=why)
        if better:
            augmented = again
    tests_before = {r.name: record_tests(model, r, max(start, first.get(r.name, 0)))[0] for r in records}
    tests_after = {r.name: record_tests(augmented, r, max(start, first.get(r.name, 0)))[0] for r in records}
    resid_before = {r.name: (r.dcl - predict(model, r).total)[first.get(r.name, 0):] for r in records}
    resid_after = {r.name: (r.dcl - predict(augmented, r).total)[first.get(r.name, 0):] for r in records}
    measured = {r.name: r.dcl[first.get(r.name, 0):] for r in records}
    report = report_dict(
        baseline={n: scores(z, z - resid_before[n]) for n, z in measured.items()},
        augmented={n: scores(z, z - resid_after[n]) for n, z in measured.items()},
        trials=trials,
        unexplained=unexplained(search.tests(best.members), fp, trials, (len(train) - start) / fs,
                                drift_holds=_holds_out(singles[ZeroDriftEffect.name], judge, base, opt)),
        fingerprint=fp_note,
        references={train.name: ref.to_dict(),
                    **{r.name: reference(model.fingerprint, model, r, start).to_dict() for r in validate}},
        fit_target=target_note,
        reestimation=refit,
        selection={"pool": pool, "chosen": list(best.members), "combinations": table,
                   "rule": "every member lowers the validation error significantly; within "
                           f"{100 * opt.parsimony:g} % of the lowest level-free validation RMSE (each "
                           "record's mean error taken out), the most members whose evidence departs from "
                           "the fingerprint, then the fewest parameters"},
        scoring="whole records from rest (rtlift validate's numbers); a periodic_disturbance's "
                "line phases are estimated on each record itself, as rtlift validate does",
        not_built=None,        # the generic diagnosis's list; every lift effect is in the catalog
    )
    return Diagnosis(report, model, augmented, trials, tests_before, tests_after, resid_before,
                     resid_after, start, table)


def _holds_out(single: tuple, judge: _Judge, base: _Node, opt: DiagnoseOptions) -> bool:
    """Does a candidate fitted alone (``singles`` entry) lower the held-out error at the bar a
    member with departing evidence needs (t ≥ ``min_t_confirm``)?"""
    node, dep, _, _ = single
    if dep is None or node.failed:
        return False
    return judge.verdict(base.errors, node.errors, dataclasses.replace(opt, min_t=opt.min_t_confirm))[0]

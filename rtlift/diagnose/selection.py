"""The one selection engine: candidates fitted alone, a pool, combinations compared on held-out
records, every member earning its place, one choice, one report — for every model kind.

A model kind offers its candidates through :class:`Candidates` (a lift model's effects,
:class:`rtlift.diagnose.lift.LiftCandidates`; a generic ``t,u,y`` model's structures,
:class:`rtlift.sysid.diagnose.GenericCandidates`): the model and its errors on the validation
records, the candidate names in the order a combination is built, how one candidate is fitted on
the model with the ones before it, the parameters a combination spends, and the kind's texts.
:func:`run` walks them:

1. **Candidates alone.** Each candidate is fitted alone on the model and judged against it on
   the validation records, which no fit ever sees (:meth:`Judge.verdict`); its evidence
   (:meth:`Candidates.evidence`) is recomputed on the model's training residual.
2. **Pool.** Where the kind screens (``screened``: a lift model's effects, which stack, so that
   combinations of them multiply), a candidate enters the pool when its fit is interior (no
   parameter on a bound of its range: a fade to 0, a "mode" damped like a lag) and it either
   lowers the validation error significantly or its evidence departs from the fingerprint, and
   it lowers the pooled validation RMSE; best first, at most ``pool_size``; then each other
   candidate fitted beside the best of them that lowers the validation error further (a strong
   effect can hide a weak one from a fit on the baseline). Where it does not (a generic model's
   structures: whole models, alternatives of one another, one member each), every candidate
   fitted enters, in the kind's order.
3. **Combinations** of up to ``max_members`` pool members (exclusive pairs left out) are built
   in the kind's order, each member fitted on the model with the ones before it (each prefix
   fitted once, :class:`Search`), and scored on the validation records.
4. **Every member earns its place.** A combination is admissible only if removing any one
   member makes the validation error significantly worse (:meth:`Judge.verdict`: relative
   RMSE gain ≥ ``min_gain``, a Diebold–Mariano t ≥ ``min_t`` over blocks, no record worse by
   more than 1 %, ρ not lower by more than 0.005; :func:`rtlift.diagnose.significance.significant_gain`).
   A member whose own evidence departs from the fingerprint (:meth:`Candidates.confirmed`)
   needs t ≥ ``min_t_confirm`` only: the training record formed the hypothesis, independently
   of the held-out records, which then confirm it; a member without such evidence is a search
   over the candidates and needs the stricter ``min_t`` (:meth:`Search.earns`). Among the
   admissible combinations (the empty one included) within ``parsimony`` of the lowest
   ``score`` (a lift model's: the *level-free* validation RMSE, each record's own mean error
   taken out, :func:`~rtlift.diagnose.significance.level_free_rmse`, :mod:`rtlift.diagnose.lift`
   says why; a generic model's: the pooled RMSE, parsimony 0), the one ranked first by the
   kind's :meth:`Candidates.rank` wins, then the one with the lowest score, then the first
   built. Admissibility stays on the raw error.

What the engine then asks the kind: the entries as reported (:meth:`Candidates.trials`: effect
or structure, why in or out), the chosen model refined (:meth:`Candidates.refine`), what stays
unexplained, every record scored and tested before and after (:meth:`Candidates.evaluate`); the
report is :func:`rtlift.diagnose.diagnosis.report_dict`'s, the same keys for every kind.

Where the kinds differ (and only there): how a candidate is fitted (an effect stacked on the
model with the ones before it; a structure re-identified whole), whether the pool screens and how
many members a combination holds (above), the choice's score, parsimony and rank (a lift model's
level misfit differs between record types; a generic model has no fingerprint), the confirmation
bar (evidence against a fingerprint: lift only), the refinement (φ and the Wiener scale
re-estimated: lift only), and the texts.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from itertools import combinations
from typing import Any, Protocol

import numpy as np

from rtlift.diagnose.diagnosis import DiagnoseOptions, Diagnosis, Trial, report_dict
from rtlift.diagnose.significance import combination, level_free_rmse, pooled_rmse, significant_gain
from rtlift.residual.fingerprint import Departure
from rtlift.residual.stats import TestResult, cluster_ols

Errors = list[np.ndarray]
"""A model's errors on the validation records (measured − predicted), each from its first scored sample."""


@dataclass
class Node:
    """A combination: its members in the kind's order, their fits (the kind's own: an effect's
    :class:`~rtlift.effects.surgery.Fitted`, a structure's model), the model and its errors."""

    members: tuple[str, ...]
    fits: dict[str, Any]
    model: Any
    errors: Errors
    failed: str = ""                     # why a member could not be fitted here


@dataclass
class Single:
    """A candidate fitted alone (step 1): its node, its evidence (``None``: not fitted or none
    the kind has), and its verdict against the model on the validation records."""

    node: Node
    evidence: Departure | None
    ok: bool
    why: str


class Candidates(Protocol):
    """What a model kind offers the engine (module docstring)."""

    name: str
    """``lift`` or ``generic`` (:attr:`rtlift.diagnose.diagnosis.Diagnosis.kind`)."""
    base: Any
    """The model diagnosed."""
    order: tuple[str, ...]
    """The candidates, in the order a combination is built."""
    options: DiagnoseOptions
    max_members: int
    screened: bool
    parsimony: float
    measured: np.ndarray
    """The validation records' measured outputs, each from its first scored sample, pooled."""
    block: int
    """Samples per block of the significance test."""
    start: int
    """The first sample the residual tests use."""
    fingerprint: Any
    references: Any
    fit_target: Any
    rule: str
    scoring: str
    not_built: list[str] | None
    """The report's keys a kind writes as it has them; ``None`` where the kind cannot have one
    (a lift model's ``not_built``, a generic model's ``references``), a list or mapping where it
    can, empty when it has nothing (INTERFACES.md: "a key a kind cannot have is ``null``")."""

    def errors(self, model: Any) -> Errors: ...

    def fit(self, name: str, parent: Node, search: Search) -> tuple[Any, Any] | str:
        """``name`` fitted on ``parent``'s model: (its fit, the model with it), or why not."""
        ...

    def excludes(self, name: str) -> tuple[str, ...]: ...

    def n_params(self, node: Node) -> int | None:
        """Parameters the combination spends (``None``: not counted)."""
        ...

    def on_bound(self, node: Node) -> str:
        """Which members' fits ended on a bound of their range ("": none)."""
        ...

    def evidence(self, name: str, node: Node, search: Search) -> Departure | None: ...

    def confirmed(self, node: Node, name: str, search: Search) -> bool:
        """Does member ``name``'s own evidence depart from the fingerprint (step 4's lower bar)?"""
        ...

    def score(self, errors: Errors) -> float: ...

    def rank(self, node: Node, near: list[Node], search: Search) -> tuple:
        """The choice's order among the near-best admissible combinations, before the score."""
        ...

    def row_why(self, verdicts: list[tuple[str, bool, str]]) -> str:
        """A combination's row's ``why`` from its members' (name, earns, why)."""
        ...

    def trials(self, sel: Selection) -> list[Trial]: ...

    def refine(self, sel: Selection) -> tuple[Any, dict[str, Any] | None]:
        """The model reported as augmented, and the report's ``reestimation``."""
        ...

    def unexplained(self, sel: Selection, trials: list[Trial]) -> list[str]: ...

    def evaluate(self, model: Any) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray],
                                            dict[str, dict[str, TestResult]]]:
        """Per record (training first): ρ/NRMSE/RMSE, the residual from its first scored sample,
        the residual tests."""
        ...


class Judge:
    """Scores models on the validation records (the kind's :meth:`Candidates.errors`)."""

    def __init__(self, errors: Callable[[Any], Errors], measured: np.ndarray, block: int) -> None:
        self.errors, self._meas, self.block = errors, measured, block

    pooled = staticmethod(pooled_rmse)
    level_free = staticmethod(level_free_rmse)

    def encompassing(self, node: Node, rivals: list[Node], search: Search) -> float:
        """How well ``node`` holds against each rival that is not nested in it or around it
        (Davidson & MacKinnon's J test, 1981, on the held-out records): with c_A, c_B the two
        combinations' corrections to what they share, z − ŷ_shared ≈ α c_A + β c_B by least
        squares (cluster-robust over blocks); the t of α. Returns the smallest over the rivals
        (inf without one): two explanations that fit alike are told apart by which of them the
        other cannot replace."""
        worst = math.inf
        mine = set(node.members)
        for other in rivals:
            theirs = set(other.members)
            if mine <= theirs or theirs <= mine:
                continue
            shared = search.node(search.ordered(mine & theirs))
            e = np.concatenate(shared.errors)            # z − ŷ_shared
            c_a = e - np.concatenate(node.errors)         # ŷ_A − ŷ_shared
            c_b = e - np.concatenate(other.errors)
            beta, se = cluster_ols(np.column_stack([c_a, c_b]), e, self.block)
            worst = min(worst, float(beta[0] / se[0]))
        return worst

    def verdict(self, before: Errors, after: Errors, opt: DiagnoseOptions) -> tuple[bool, str]:
        """Is ``after`` significantly better than ``before`` on every count (module doc, 4)?"""
        return significant_gain(before, after, self._meas, self.block, opt)


class Search:
    """Fits combinations by extending their prefixes (each fitted once, cached)."""

    def __init__(self, kind: Candidates, judge: Judge) -> None:
        self.kind, self.judge = kind, judge
        self.nodes: dict[tuple[str, ...], Node] = {(): Node((), {}, kind.base, judge.errors(kind.base))}

    def node(self, members: tuple[str, ...]) -> Node:
        if members in self.nodes:
            return self.nodes[members]
        parent = self.node(members[:-1])
        name = members[-1]
        if parent.failed:
            node = Node(members, parent.fits, parent.model, parent.errors, parent.failed)
        else:
            fitted = self.kind.fit(name, parent, self)
            if isinstance(fitted, tuple):
                fit, model = fitted
                node = Node(members, {**parent.fits, name: fit}, model, self.judge.errors(model))
            else:
                node = Node(members, parent.fits, parent.model, parent.errors, f"{name}: {fitted}")
        self.nodes[members] = node
        return node

    def without(self, members: tuple[str, ...], name: str) -> Node:
        return self.node(tuple(m for m in members if m != name))

    def ordered(self, names: Iterable[str]) -> tuple[str, ...]:
        """``names`` in the kind's order."""
        names = set(names)
        return tuple(n for n in self.kind.order if n in names)

    def compatible(self, names: tuple[str, ...]) -> bool:
        return not any(x in self.kind.excludes(n) for n in names for x in names)

    def earns(self, node: Node, name: str, opt: DiagnoseOptions) -> tuple[bool, str]:
        """Does member ``name`` earn its place in ``node`` (module docstring, 4)? Its removal must
        make the validation error significantly worse: t ≥ ``opt.min_t``, or t ≥
        ``opt.min_t_confirm`` where its own evidence on the training record departs from the
        fingerprint (the held-out records then confirm a hypothesis the training record formed)."""
        before = self.without(node.members, name).errors
        ok, why = self.judge.verdict(before, node.errors, opt)
        if ok or opt.min_t_confirm >= opt.min_t or not self.kind.confirmed(node, name, self):
            return ok, why
        ok, why = self.judge.verdict(before, node.errors, dataclasses.replace(opt, min_t=opt.min_t_confirm))
        return ok, f"{why} (its evidence departs from the fingerprint: t >= {opt.min_t_confirm:g} confirms it)"


@dataclass
class Selection:
    """What the search found (steps 1–4): the candidates alone, the pool, the combinations'
    rows (:func:`rtlift.diagnose.significance.combination`) and the chosen one."""

    search: Search
    judge: Judge
    base: Node
    singles: dict[str, Single]
    pool: list[str]
    table: list[dict[str, Any]]
    best: Node


def select(kind: Candidates) -> Selection:
    """Steps 1–4 of the module docstring on ``kind``'s candidates."""
    opt = kind.options
    judge = Judge(kind.errors, kind.measured, kind.block)
    search = Search(kind, judge)
    base = search.node(())
    rb = judge.pooled(base.errors)

    # 1: candidates alone
    singles: dict[str, Single] = {}
    for name in kind.order:
        node = search.node((name,))
        if node.failed:
            singles[name] = Single(node, None, False, node.failed.split(": ", 1)[1])
            continue
        ok, why = judge.verdict(base.errors, node.errors, opt)
        singles[name] = Single(node, kind.evidence(name, node, search), ok, why)

    # 2: the pool
    if kind.screened:
        pool = [n for n, s in singles.items()
                if s.evidence is not None and not kind.on_bound(s.node) and (s.ok or s.evidence.departs)
                and judge.pooled(s.node.errors) < rb]
        pool = sorted(pool, key=lambda n: judge.pooled(singles[n].node.errors))[:opt.pool_size]
        if pool:     # forward screening: a strong effect can hide a weak one from a fit on the baseline
            lead = pool[0]
            for name in kind.order:
                if name in pool or not search.compatible((lead, name)) or len(pool) >= opt.pool_size:
                    continue
                pair = search.node(search.ordered((lead, name)))
                if pair.failed or kind.on_bound(pair):
                    continue
                if judge.verdict(singles[lead].node.errors, pair.errors, opt)[0]:
                    pool.append(name)
    else:
        pool = [n for n, s in singles.items() if not s.node.failed]

    # 3-4: combinations, admissibility, choice
    table = []
    admissible = [base]
    for size in range(1, min(kind.max_members, len(pool)) + 1):
        for combo in combinations(search.ordered(pool), size):
            if not search.compatible(combo):
                continue
            node = search.node(combo)
            count = kind.n_params(node) if not node.failed else None
            bound = "" if node.failed else kind.on_bound(node)
            if node.failed:
                row = combination(combo, node.errors, count, False, f"not fitted: {node.failed}")
            elif bound:
                row = combination(combo, node.errors, count, False, f"on a bound: {bound}")
            else:
                verdicts = [(m, *search.earns(node, m, opt)) for m in combo]
                earned = all(ok for _, ok, _ in verdicts)
                row = combination(combo, node.errors, count, earned, kind.row_why(verdicts))
                if earned:
                    admissible.append(node)
            table.append(row)
    score = {n.members: kind.score(n.errors) for n in admissible}
    lowest = min(score.values())
    near = [n for n in admissible if score[n.members] <= lowest * (1 + kind.parsimony)]
    best = min(near, key=lambda n: (*kind.rank(n, near, search), score[n.members]))
    return Selection(search, judge, base, singles, pool, table, best)


def run(kind: Candidates) -> Diagnosis:
    """The diagnosis of ``kind``'s model (module docstring): the selection, the entries as
    reported, the chosen model refined, every record scored and tested before and after, and
    the report."""
    sel = select(kind)
    trials = kind.trials(sel)
    augmented, reestimation = kind.refine(sel)
    scores_before, resid_before, tests_before = kind.evaluate(kind.base)
    scores_after, resid_after, tests_after = kind.evaluate(augmented)
    report = report_dict(
        baseline=scores_before,
        augmented=scores_after,
        trials=trials,
        unexplained=kind.unexplained(sel, trials),
        fingerprint=kind.fingerprint,
        references=kind.references,
        fit_target=kind.fit_target,
        reestimation=reestimation,
        selection={"pool": sel.pool, "chosen": list(sel.best.members), "combinations": sel.table,
                   "rule": kind.rule},
        scoring=kind.scoring,
        not_built=kind.not_built,
    )
    return Diagnosis(report, kind.base, augmented, trials, tests_before, tests_after, resid_before,
                     resid_after, kind.start, sel.table, kind.name)

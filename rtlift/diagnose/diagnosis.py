"""What a diagnosis is asked and what it gives, for every model kind the selection engine
(:mod:`rtlift.diagnose.selection`) walks — a lift model's effects (:mod:`rtlift.diagnose.lift`), a
generic ``t,u,y`` model's structures (:mod:`rtlift.sysid.diagnose`): the options
(:class:`DiagnoseOptions`), one candidate's outcome as reported (:class:`Trial`), the report
(:func:`report_dict`) and the diagnosis as :mod:`rtlift.diagnose.report` writes it
(:class:`Diagnosis`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rtlift.residual.stats import TestResult

REPORT_VERSION = 1


@dataclass(frozen=True)
class DiagnoseOptions:
    min_gain: float = 0.015       # relative validation RMSE decrease a member must bring
    min_t: float = 3.0            # significance of that decrease (1 s blocks)
    min_t_confirm: float = 2.0    # the same for a member whose own evidence departs from the fingerprint
    max_effects: int = 3          # largest combination compared
    pool_size: int = 5            # candidates that enter the combinations
    parsimony: float = 0.02       # combinations this close to the best compete on evidence, then size
    suspect: str | None = None    # an effect other evidence names (--adapt: the departure's): first among near-ties


@dataclass
class Trial:
    """One catalog entry's outcome, as reported."""

    name: str
    accepted: bool
    params: dict[str, Any]
    evidence: str
    rmse_before: float
    rmse_after: float
    kind: str = "effect"
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "accepted": self.accepted,
                "params": _plain(self.params), "evidence": self.evidence,
                "validation_rmse_before": self.rmse_before, "validation_rmse_after": self.rmse_after}


def report_dict(baseline: dict[str, Any], augmented: dict[str, Any], trials: list[Trial], unexplained: Any,
                fingerprint: Any, references: Any, fit_target: Any, reestimation: Any, selection: dict[str, Any],
                scoring: str, not_built: list[str] | None) -> dict[str, Any]:
    """The report (INTERFACES.md's keys, in this order) of a diagnosis of either kind: ρ, NRMSE and
    RMSE per record before and after (``baseline``, ``augmented``: ``{record: scores}``), every
    entry tried, what stays unexplained, what the residual was compared with, the selection, how
    the records were scored, and the structures not built. One convention for a key a kind
    cannot have (INTERFACES.md): ``None`` (``null``) — a lift model's ``not_built`` (every lift
    effect is in the catalog), a generic model's ``references`` and ``reestimation`` (no
    fingerprint; each structure is re-identified whole); a key it can have is its list or mapping,
    empty when there is nothing in it (a generic model's ``not_built`` today: ``[]``)."""
    return {
        "version": REPORT_VERSION,
        "baseline": {"records": baseline},
        "augmented": {"records": augmented},
        "effects": [t.to_dict() for t in trials],
        "unexplained": unexplained,
        "fingerprint": fingerprint,
        "references": references,
        "fit_target": fit_target,
        "reestimation": reestimation,
        "selection": selection,
        "scoring": scoring,
        "not_built": not_built,
    }


@dataclass
class Diagnosis:
    """A diagnosis of either kind, as :mod:`rtlift.diagnose.report` writes it: the report (the same
    keys for both), the models, the entries tried, the residual tests and residuals per record
    (from its first scored sample; tested from ``start`` on), the combinations compared."""

    report: dict[str, Any]
    baseline: Any          # a lift model (:class:`rtlift.model.hybrid.HybridModel`), or a generic one (``kind``)
    augmented: Any
    trials: list[Trial]
    tests_before: dict[str, dict[str, TestResult]]
    tests_after: dict[str, dict[str, TestResult]]
    residual_before: dict[str, np.ndarray]
    residual_after: dict[str, np.ndarray]
    start: int
    rounds: list[dict[str, Any]] = field(default_factory=list)
    kind: str = "lift"
    """``lift`` (a :class:`HybridModel`) or ``generic`` (a single-input ``t,u,y`` model of
    :mod:`rtlift.model.siso`)."""


def _plain(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _plain(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_plain(v) for v in d]
    if isinstance(d, (float, np.floating)):
        return float(d)
    if isinstance(d, np.integer):
        return int(d)
    return d

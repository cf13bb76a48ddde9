"""The one selection engine (:mod:`rtlift.diagnose.selection`) on a toy kind whose answer is
known: the measured output is 0.8·s₀ + 1.0·s₁ + 0.5·s₂ + noise, the model 0.8·s₀, the candidates
add s₁, s₂ or an unrelated s₃ with a gain fitted on the training half; the engine must keep exactly s₁ and s₂ (stacked,
screened kind) or the better single (one member each, pooled score: the generic kind's rule), and
both real kinds must offer what the engine asks."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.diagnose.diagnosis import DiagnoseOptions, Trial
from rtlift.diagnose.lift import LiftCandidates
from rtlift.diagnose.selection import Candidates, Node, run, select
from rtlift.diagnose.significance import level_free_rmse, pooled_rmse
from rtlift.residual.fingerprint import Departure
from rtlift.sysid.diagnose import GenericCandidates

N = 4000
rng = np.random.default_rng(7)
t = np.arange(2 * N)
SIGNALS = {"s0": t / (2.0 * N), "s1": np.sin(2 * np.pi * t / 400.0), "s2": np.sign(np.sin(2 * np.pi * t / 170.0)),
           "s3": rng.standard_normal(2 * N)}
Z = 0.8 * SIGNALS["s0"] + 1.0 * SIGNALS["s1"] + 0.5 * SIGNALS["s2"] + 0.2 * rng.standard_normal(2 * N)
TRAIN, VALIDATE = slice(0, N), [slice(N, N + N // 2), slice(N + N // 2, 2 * N)]


class Toy:
    """Candidates adding a signal with a gain fitted on the training half (a model is the dict
    of gains)."""

    name = "toy"
    base = {"s0": 0.8}
    order = ("s1", "s2", "s3")
    options = DiagnoseOptions()
    start = 0
    fingerprint = references = fit_target = reestimation = None
    rule = scoring = "toy"
    not_built = None

    def __init__(self, screened: bool, max_members: int, parsimony: float, score) -> None:
        self.screened, self.max_members, self.parsimony, self.score = screened, max_members, parsimony, score
        self.measured = np.concatenate([Z[s] for s in VALIDATE])
        self.block = 100

    @staticmethod
    def predict(model: dict[str, float], part: slice) -> np.ndarray:
        return sum((g * SIGNALS[n][part] for n, g in model.items()), np.zeros(part.stop - part.start))

    def errors(self, model):
        return [Z[s] - self.predict(model, s) for s in VALIDATE]

    def fit(self, name, parent: Node, search):
        r = Z[TRAIN] - self.predict(parent.model, TRAIN)
        x = SIGNALS[name][TRAIN]
        gain = float(x @ r / (x @ x))
        return gain, {**parent.model, name: gain}

    def excludes(self, name):
        return ()

    def n_params(self, node):
        return len(node.members)

    def on_bound(self, node):
        return ""

    def evidence(self, name, node, search):
        return Departure(0.0, False, "no evidence")     # the pool then asks for a significant gain

    def confirmed(self, node, name, search):
        return False

    def rank(self, node, near, search):
        return (len(node.members),)

    def row_why(self, verdicts):
        return "; ".join(why for _, _, why in verdicts)

    def trials(self, sel):
        rb = sel.judge.pooled(sel.base.errors)
        return [Trial(n, n in sel.best.members, {"gain": sel.singles[n].node.fits[n]}, sel.singles[n].why, rb,
                      sel.judge.pooled(sel.singles[n].node.errors)) for n in self.order]

    def refine(self, sel):
        return sel.best.model, None

    def unexplained(self, sel, trials):
        return []

    def evaluate(self, model):
        e = {"train": Z[TRAIN] - self.predict(model, TRAIN)}
        return {"train": {"rmse": pooled_rmse([e["train"]])}}, e, {"train": {}}


def test_a_stacked_screened_kind_keeps_exactly_the_two_signals_with_their_gains():
    """Pool and combinations as a lift model's: s₃ does not lower the error and stays out;
    s₁ + s₂ is admissible (each member's removal significantly worse), the gains near 1.0 and 0.5."""
    kind = Toy(screened=True, max_members=3, parsimony=0.02, score=level_free_rmse)
    sel = select(kind)
    assert "s3" not in sel.pool and set(sel.pool) == {"s1", "s2"}
    assert sel.best.members == ("s1", "s2")
    assert sel.best.fits["s1"] == pytest.approx(1.0, abs=0.02)
    assert sel.best.fits["s2"] == pytest.approx(0.5, abs=0.02)
    rows = {tuple(r["members"]): r for r in sel.table}
    assert rows[("s1", "s2")]["admissible"] and rows[("s1", "s2")]["parameters"] == 2
    # the chosen combination's validation RMSE is the noise's (0.2), the model's error without it is not
    assert rows[("s1", "s2")]["validation_rmse"] == pytest.approx(0.2, rel=0.05)
    assert sel.judge.pooled(sel.base.errors) > 0.5


def test_one_member_kind_chooses_the_lowest_pooled_admissible_single():
    """The generic kind's rule: one member each, every fitted candidate compared, the lowest pooled
    RMSE among the admissible (parsimony 0): s₁ (it explains 1.0² of the variance, s₂ 0.5²)."""
    kind = Toy(screened=False, max_members=1, parsimony=0.0, score=pooled_rmse)
    sel = select(kind)
    assert sel.pool == ["s1", "s2", "s3"]
    assert [r["members"] for r in sel.table] == [["s1"], ["s2"], ["s3"]]
    admissible = [r for r in sel.table if r["admissible"]]
    assert sel.best.members == tuple(min(admissible, key=lambda r: r["validation_rmse"])["members"]) == ("s1",)
    assert not next(r for r in sel.table if r["members"] == ["s3"])["admissible"]


def test_run_writes_one_report_with_the_interfaces_keys():
    report = run(Toy(screened=True, max_members=3, parsimony=0.02, score=level_free_rmse)).report
    assert list(report) == ["version", "baseline", "augmented", "effects", "unexplained", "fingerprint",
                            "references", "fit_target", "reestimation", "selection", "scoring", "not_built"]
    assert report["selection"]["chosen"] == ["s1", "s2"]
    assert [e["accepted"] for e in report["effects"]] == [True, True, False]
    assert report["augmented"]["records"]["train"]["rmse"] == pytest.approx(0.2, rel=0.05)


@pytest.mark.parametrize("kind", [LiftCandidates, GenericCandidates])
def test_both_model_kinds_offer_everything_the_engine_asks(kind):
    """Every attribute and method of the protocol is declared by both kinds (the instance
    attributes set in ``__init__``, read from its source)."""
    import inspect

    asked = [n for n in dir(Candidates) if not n.startswith("_")] + list(Candidates.__annotations__)
    source = inspect.getsource(kind.__init__)
    missing = [n for n in set(asked) if not hasattr(kind, n) and f"self.{n}" not in source]
    assert missing == [], missing

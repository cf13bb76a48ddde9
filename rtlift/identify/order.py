"""The Wiener LTI's order: the smallest whose held-out error is near the best (Ljung §16.4
'cross-validation'), AIC reported beside it."""

from __future__ import annotations

from dataclasses import dataclass

from rtlift.identify.pem import PEMResult


@dataclass(frozen=True)
class OrderChoice:
    """Candidates n → (estimation RMSE, held-out RMSE, AIC) and the chosen order."""

    order: int
    table: list[dict]
    rule: str


def choose_order(candidates: dict[int, tuple[PEMResult, float]], tolerance: float = 0.01) -> OrderChoice:
    """Smallest n whose held-out RMSE is within ``tolerance`` (relative) of the best
    (parsimony; Ljung §16.4 'cross-validation'); AIC is reported beside it."""
    best = min(v[1] for v in candidates.values())
    chosen = min(n for n, (_, e) in candidates.items() if e <= best * (1 + tolerance))
    table = [{"order": n, "rmse_estimation": r.rmse, "rmse_holdout": e, "aic": r.aic}
             for n, (r, e) in sorted(candidates.items())]
    return OrderChoice(chosen, table,
                       f"smallest order within {100 * tolerance:.0f} % of the best held-out RMSE")

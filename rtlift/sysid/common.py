"""What the single-input fits share (:mod:`.identify`, :mod:`.feedback`, :mod:`.store_chain`):
their options, the limits on a model's output or state, and the held-out score a fit is kept by.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtlift.model.siso import FeedbackModel, SaturatedModel, SisoModel


@dataclass(frozen=True)
class SisoOptions:
    orders: tuple[int, ...] = (2, 4, 6)
    knots: int = 16
    more_knots: tuple[int, ...] = (48, 96)
    more_knots_nfev: int = 100
    holdout: float = 0.2
    skip: int = 200
    keep: int = 3
    cost_samples: int = 30000
    max_nfev: int = 400
    feedback_orders: tuple[int, ...] = (2, 3, 4, 5, 6)
    chain_starts: int = 12


Limits = tuple[float, float]
NO_LIMITS: Limits = (-np.inf, np.inf)


def _limited(model, limits: Limits):
    """``model`` with its output clipped at ``limits`` (unchanged when there are none)."""
    return model if limits == NO_LIMITS else SaturatedModel(model, *limits)


def _rmse(model: SisoModel | FeedbackModel, u: np.ndarray, y: np.ndarray, skip: int) -> float:
    """RMSE of the free run from rest over (u, y), samples ``skip`` on."""
    return _pooled_rmse(model, [(u, y, skip)])


def _pooled_rmse(model: SisoModel | FeedbackModel, parts: list[tuple[np.ndarray, np.ndarray, int]]) -> float:
    """RMSE pooled over several records (u, y, first scored sample), each a free run from rest."""
    err = []
    for u, y, start in parts:
        model.reset()
        err.append((model.simulate(u) - y)[start:])
    model.reset()
    return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))

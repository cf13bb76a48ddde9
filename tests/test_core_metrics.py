"""Metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.core.metrics import corr, fit_percent, nrmse, rmse, scores


def test_metrics_match_their_definitions():
    a = np.array([1.0, 2.0, 3.0, 4.0])
    b = np.array([1.5, 2.0, 2.5, 4.5])
    assert rmse(a, b) == pytest.approx(np.sqrt((0.25 + 0 + 0.25 + 0.25) / 4))
    assert nrmse(a, b) == pytest.approx(rmse(a, b) / np.std(a))
    assert corr(a, b) == pytest.approx(np.corrcoef(a, b)[0, 1], abs=1e-15)
    assert fit_percent(a, b) == pytest.approx(100 * (1 - np.sqrt(0.75) / np.sqrt(5.0)))


def test_correlation_ignores_offset_and_scale_but_rmse_does_not():
    rng = np.random.default_rng(0)
    a = rng.normal(size=1000)
    s = scores(a, 3 * a + 1)
    assert s["corr"] == pytest.approx(1.0, abs=1e-12)
    assert s["rmse"] > 1.0


def test_mismatched_lengths_raise():
    with pytest.raises(ValueError):
        rmse(np.zeros(3), np.zeros(4))

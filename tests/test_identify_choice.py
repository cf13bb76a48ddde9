"""Which lift structure ``rtlift identify`` fits (issue 31), and the noise ceiling the burst
benchmark scores models against."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.core.metrics import noise_ceiling, scores
from rtlift.core.records import Record
from rtlift.identify.choice import choose_structure
from rtlift.identify.kernel import burst_scatter_std

FS = 400.0


def _train(period: int, n: int = 2000, name: str = "train") -> Record:
    cmu = np.where(np.arange(n) % period < 4, 0.0022, 0.0)
    return Record(np.arange(n) / FS, cmu, np.full(n, 0.0022), np.zeros(n), name=name)


def test_burst_trains_choose_the_interaction_structure_and_say_why():
    choice = choose_structure([_train(229, name="train_T7"), _train(57, name="train_T1p75")])
    assert choice.name == "interaction"
    assert "train_T7 (bursts every 0.572 s)" in choice.why and "train_T1p75 (bursts every 0.142 s)" in choice.why


def test_without_trains_the_papers_hybrid_is_chosen():
    assert choose_structure([]).name == "paper"


@pytest.mark.parametrize("requested", ["paper", "interaction"])
def test_an_asked_for_structure_wins(requested):
    choice = choose_structure([_train(114)], requested)
    assert choice.name == requested and choice.why.startswith(f"asked for (--structure {requested})")


def test_a_train_record_without_bursts_is_refused():
    silent = Record(np.arange(500) / FS, np.zeros(500), np.zeros(500), np.zeros(500), name="silent")
    with pytest.raises(ValueError, match="no burst in the train record.*silent"):
        choose_structure([silent])


def test_noise_ceiling_is_what_the_noise_free_signal_scores():
    rng = np.random.default_rng(1)
    s = 0.05 * np.sin(2 * np.pi * np.arange(40000) / 800)
    a = s + rng.normal(0, 0.02, s.size)
    expect, got = scores(a, s), noise_ceiling(a, 0.02)
    assert got["corr"] == pytest.approx(expect["corr"], abs=0.003)
    assert got["nrmse"] == pytest.approx(expect["nrmse"], rel=0.01)


def test_burst_scatter_is_the_noise_around_repeated_identical_bursts():
    """20 identical responses (a decaying lift, the same every time) plus white noise of σ 0.003:
    the scatter across bursts is σ (within the sampling error of ≈ 20 × 300 samples)."""
    rng = np.random.default_rng(2)
    n, period = 20 * 300 + 50, 300
    cmu = np.where((np.arange(n) % period < 4) & (np.arange(n) >= 10), 0.0022, 0.0)
    response = np.convolve(cmu, 3.0 * np.exp(-np.arange(200) / 40.0))[:n]
    dcl = response + rng.normal(0, 0.003, n)
    assert burst_scatter_std(cmu, dcl) == pytest.approx(0.003, rel=0.05)
    assert np.isnan(burst_scatter_std(np.zeros(n), dcl))

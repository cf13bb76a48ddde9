"""Issues 18 and 31 on a plant nobody here wrote (``../shared/data/independent_plant``): the
interaction structure, identified on its campaign with the trains (what ``rtlift identify``
chooses for them), scored on every record type of ``clean/`` against the ceiling — the plant's
noise-free lift, estimated from the noise of the same seed's single bursts (the records carry no
noise-free lift; on the bench the estimate is within 0.003 of the truth, benchmarks/burst_patterns.py).

These tests read ``../shared`` and skip, with that reason, in a clone without it.
"""

from __future__ import annotations

import pytest

from benchmarks.independent_plant import DEFAULT_DATA
from rtlift.core.metrics import noise_ceiling
from rtlift.core.records import read_record
from rtlift.identify.campaign import identify_hybrid
from rtlift.identify.interaction import identify_interaction
from rtlift.identify.kernel import burst_scatter_std
from rtlift.model.validation import validate_record

pytestmark = pytest.mark.skipif(not (DEFAULT_DATA / "campaign" / "static.csv").exists(),
                                reason=f"the independent plant's development set is not at {DEFAULT_DATA} "
                                       "(it lives in ../shared, beside the project, not in a clone)")

RECORDS = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125", "sine_k025", "random")


@pytest.fixture(scope="module")
def camp():
    return {n: read_record(DEFAULT_DATA / "campaign" / f"{n}.csv") for n in
            ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125")}


@pytest.fixture(scope="module")
def model(camp):
    return identify_interaction(camp["static"], camp["single_burst"],
                                [camp[t] for t in ("train_T1p75", "train_T3p5", "train_T7")], camp["sine_k0125"]).model


@pytest.fixture(scope="module")
def noise():
    burst = read_record(DEFAULT_DATA / "clean" / "single_burst.csv")
    return burst_scatter_std(burst.cmu, burst.dcl)


@pytest.mark.parametrize("name", RECORDS)
def test_interaction_model_is_within_reach_of_the_ceiling_on_every_clean_record(model, noise, name):
    """ρ ≥ ceiling ρ − 0.02 and NRMSE ≤ max(0.5, ceiling NRMSE + 0.1) (issue 31's goal) on records
    of another noise seed; the paper's hybrid gets ρ 0.02 / 0.16 on single_burst / train_T7."""
    rec = read_record(DEFAULT_DATA / "clean" / f"{name}.csv")
    s, ceiling = validate_record(model, rec).scores, noise_ceiling(rec.dcl, noise)
    assert s["corr"] >= ceiling["corr"] - 0.02, (s, ceiling)
    assert s["nrmse"] <= max(0.5, ceiling["nrmse"] + 0.1), (s, ceiling)


def test_interaction_model_is_as_good_as_the_papers_hybrid_on_the_faster_sine(model, camp):
    """clean/sine_k025 (twice the training record's frequency): the delivered envelope drives the
    slow part without m's lag. Measured ρ / NRMSE 0.978 / 0.22, the hybrid (identified on the
    sine alone) 0.973 / 0.34. (On random it is 0.981 / 0.28 against the hybrid's 0.984 / 0.19.)"""
    rec = read_record(DEFAULT_DATA / "clean" / "sine_k025.csv")
    hybrid = identify_hybrid(camp["static"], camp["single_burst"], camp["sine_k0125"]).model
    s, h = validate_record(model, rec).scores, validate_record(hybrid, rec).scores
    assert s["corr"] >= h["corr"] and s["nrmse"] <= h["nrmse"] - 0.05, (s, h)

"""Issue 18 on a plant nobody here wrote (``../shared/data/independent_plant``): the interaction
structure, identified on its campaign with the trains, fits every record type of ``clean/``.

These tests read ``../shared`` and skip, with that reason, in a clone without it.
"""

from __future__ import annotations

import pytest

from benchmarks.independent_plant import DEFAULT_DATA
from rtlift.core.records import read_record
from rtlift.identify.interaction import identify_interaction
from rtlift.model.validation import validate_record

pytestmark = pytest.mark.skipif(not (DEFAULT_DATA / "campaign" / "static.csv").exists(),
                                reason=f"the independent plant's development set is not at {DEFAULT_DATA} "
                                       "(it lives in ../shared, beside the project, not in a clone)")

RECORDS = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125", "sine_k025", "random")


@pytest.fixture(scope="module")
def model():
    camp = {n: read_record(DEFAULT_DATA / "campaign" / f"{n}.csv") for n in
            ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125")}
    return identify_interaction(camp["static"], camp["single_burst"],
                                [camp[t] for t in ("train_T1p75", "train_T3p5", "train_T7")], camp["sine_k0125"]).model


@pytest.mark.parametrize("name", RECORDS)
def test_interaction_model_meets_the_goal_on_every_clean_record(model, name):
    """ρ ≥ 0.9 and NRMSE ≤ 0.5 (issue 18's goal) on records of another noise seed. Measured:
    the worst are single_burst 0.905 / 0.44 and train_T7 0.909 / 0.44; the paper's hybrid gets
    −0.07 / 1.33 and 0.13 / 2.30 there."""
    s = validate_record(model, read_record(DEFAULT_DATA / "clean" / f"{name}.csv")).scores
    assert s["corr"] >= 0.9 and s["nrmse"] <= 0.5, s

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
from rtlift.identify.kernel import burst_scatter_std
from rtlift.model.modelfile import load_model
from rtlift.model.validation import validate_record
from testkit.shared import identified
from tests.test_diagnose_independent_plant import identify_args

pytestmark = pytest.mark.skipif(not (DEFAULT_DATA / "campaign" / "static.csv").exists(),
                                reason=f"the independent plant's development set is not at {DEFAULT_DATA} "
                                       "(it lives in ../shared, beside the project, not in a clone)")

RECORDS = ("static", "single_burst", "train_T1p75", "train_T3p5", "train_T7", "sine_k0125", "sine_k025", "random")


@pytest.fixture(scope="module")
def model():
    """What ``rtlift identify`` writes for the campaign with the trains (the interaction structure,
    its choice): the file tests/test_diagnose_independent_plant.py diagnoses with, identified once
    per run (:func:`testkit.shared.identified`)."""
    return load_model(identified(*identify_args(trains=True)))


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


@pytest.fixture(scope="module")
def hybrid():
    """The paper's hybrid as ``rtlift identify`` writes it for the campaign without the trains."""
    return load_model(identified(*identify_args(trains=False)))


@pytest.mark.parametrize("name", ["sine_k0125", "sine_k025", "random"])
def test_interaction_model_is_at_least_as_good_as_the_papers_hybrid_on_the_sines_and_random(model, hybrid, name):
    """Issue 31's first deliverable, on records of another noise seed: ρ not lower and NRMSE not
    higher than the paper's hybrid (identified on the sine alone). Measured ρ / NRMSE, the static
    lift as the Wiener input: sine_k0125 0.993 / 0.13 (hybrid 0.991 / 0.18), sine_k025 0.978 / 0.22
    (0.973 / 0.34), random 0.989 / 0.16 (0.984 / 0.19); with u before it random was 0.981 / 0.28."""
    rec = read_record(DEFAULT_DATA / "clean" / f"{name}.csv")
    s, h = validate_record(model, rec).scores, validate_record(hybrid, rec).scores
    assert s["corr"] >= h["corr"] and s["nrmse"] <= h["nrmse"], (s, h)


def test_the_static_lift_drives_the_slow_part_and_the_level_on_random_is_right(model):
    """The plant's mean lift on every record is the mean of its static map over the envelope; the
    identification chooses the static lift as the Wiener input (held-out error), and the model's
    mean residual on clean random is then +0.003 (with u, +0.008)."""
    stage = model.input_stages[-1]
    assert stage.lift is not None and stage.power >= 2, stage.params()
    rec = read_record(DEFAULT_DATA / "clean" / "random.csv")
    model.reset()
    resid = rec.dcl - model.simulate(rec.cmu, rec.cmu_envelope).total
    model.reset()
    assert abs(float(resid[400:].mean())) < 0.005

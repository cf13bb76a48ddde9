"""The diagnosis on a plant nobody here wrote: the development set in ``../shared/data/independent_plant``.

The README's protocol, through the command line: ``rtlift identify`` with defaults on the clean
campaign, ``rtlift diagnose`` per case (train sine_k0125, validate sine_k025 and random), and
``rtlift validate`` of ``model_augmented.json``. A case is right when the accepted entries of kind
``effect`` are exactly the truth's names, the key parameters are close and at least half of the
error the effect added is recovered (or, where it added < 10 %, the model is no worse).

All eight cases are right and are asserted so, with four mixes composed from them (drift plus
pickup, resonance plus drift, resonance plus pickup, hysteresis plus pickup) and a hysteresis of
half the size; and in the README's user form (records renamed, training on ``random``), on the
paper's hybrid and on the model identified with the trains. Parameters the set does not show,
made from ``clean`` (``benchmarks.independent_plant --variants``): delays of 8 and 36 samples, a
mode at 18 Hz and 50 Hz pickup on the hybrid; a positive drift and a ramp on the trains' model
only (the hybrid misses both, docs/RESULTS.md says why).

The hysteresis case became right when the diagnosis began to fit an effect that replaces the
static map to what changed since identification: the training record repeats the campaign's
sine_k0125 experiment (the same input), so the model's own misfit on that run, which the map
shares, is taken out before the fit (a direction-dependent gain fitted to the raw residual took
that misfit for half the effect and recovered 36 % on ``random``). Its imprint is a gain that
switches with the flow's own state (the lift), between about 0.88 and 1.12.

The resonance case became right when identification began to refine the kernel's first burst
period on the training record: the mode (31 Hz) sits on the 4th burst harmonic, and the
single-burst kernel's harmonic there was a quarter of the plant's, an error the mode then
amplified tenfold.

These tests read ``../shared`` and skip, with that reason, in a clone without it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmarks.independent_plant import (
    DEFAULT_DATA,
    FIELD_NAMES,
    FIELD_SCORED,
    FIELD_TRAIN,
    TRAINS,
    anonymize,
    compose,
    judge_case,
    run_cli,
    validate,
    variant,
)
from testkit.shared import identified

pytestmark = pytest.mark.skipif(not (DEFAULT_DATA / "campaign" / "static.csv").exists(),
                                reason=f"the independent plant's development set is not at {DEFAULT_DATA} "
                                       "(it lives in ../shared, beside the project, not in a clone)")


def identify_args(trains: bool) -> tuple[Path | str, ...]:
    """``rtlift identify``'s arguments on the clean campaign with defaults (the README's protocol):
    the paper's hybrid, or with ``trains`` the structure it chooses for the burst trains."""
    camp = DEFAULT_DATA / "campaign"
    more = ("--trains", *(camp / f"{t}.csv" for t in TRAINS)) if trains else ()
    return ("--static", camp / "static.csv", "--single-burst", camp / "single_burst.csv", *more,
            "--train", camp / "sine_k0125.csv")


def identified_copy(tmp_path_factory, folder: str, trains: bool) -> Path:
    """The model file ``rtlift identify`` writes (:func:`identify_args`), in a folder of its own.
    Run once per test run and shared with tests/test_independent_plant_interaction.py
    (:func:`testkit.shared.identified`: the same command on the same bytes, the file it wrote)."""
    out = tmp_path_factory.mktemp(folder) / "model.json"
    shutil.copyfile(identified(*identify_args(trains)), out)
    return out


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    return identified_copy(tmp_path_factory, "ip", trains=False)


@pytest.fixture(scope="module")
def clean_rmse(model) -> dict:
    return validate(model, DEFAULT_DATA / "clean", model.parent / "clean.json")


def run_case(model: Path, clean_rmse: dict, case: str | Path) -> tuple[dict, dict]:
    d = DEFAULT_DATA / case
    out = model.parent / d.name
    run_cli("diagnose", "--model", model, "--train", d / "sine_k0125.csv",
            "--validate", d / "sine_k025.csv", d / "random.csv", "--out", out)
    report = json.loads((out / "report.json").read_text())
    truth = json.loads((d / "truth.json").read_text())
    row = judge_case(case, report, truth, validate(model, d, out / "m.json"),
                     validate(out / "model_augmented.json", d, out / "a.json"), clean_rmse)
    return row, report


@pytest.mark.parametrize("case", ["clean", "delay", "resonance", "fade", "drift", "mains", "hysteresis",
                                  "delay_mains"])
def test_the_case_is_diagnosed_right_by_the_readme_protocol(model, clean_rmse, case):
    row, report = run_case(model, clean_rmse, case)
    assert row["names_ok"], (row["accepted"], row["truth"])
    assert row["params_ok"], row["params"]
    assert row["recovery_ok"], row["recovered"]
    assert row["right"]


def test_a_clean_record_accepts_nothing_at_all(model, clean_rmse):
    _, report = run_case(model, clean_rmse, "clean")
    assert [e["name"] for e in report["effects"] if e["accepted"]] == []
    assert report["augmented"] == report["baseline"]


def test_the_resonance_is_named_with_its_frequency_and_damping(model, clean_rmse):
    row, report = run_case(model, clean_rmse, "resonance")
    assert row["accepted"] == ["sensor_resonance"] and row["right"]
    entry = next(e for e in report["effects"] if e["name"] == "sensor_resonance")
    assert entry["kind"] == "effect"
    assert entry["params"]["frequency_hz"] == pytest.approx(31.0, rel=0.03)
    assert entry["params"]["damping_ratio"] == pytest.approx(0.05, rel=0.3)
    assert min(row["recovered"].values()) > 0.6


def test_the_hysteresis_is_fitted_to_what_changed_and_driven_by_the_lift(model, clean_rmse):
    row, report = run_case(model, clean_rmse, "hysteresis")
    assert row["accepted"] == ["hysteresis"] and row["right"], row
    assert [e["name"] for e in report["effects"] if e["accepted"]] == ["hysteresis"]   # nothing else
    assert "repeats the identification's sine_k0125 experiment" in report["fit_target"]
    entry = next(e for e in report["effects"] if e["name"] == "hysteresis")
    assert entry["kind"] == "effect" and "z = +" in entry["evidence"]
    assert "fitted to what changed since identification" in entry["evidence"]
    assert entry["params"]["driver"] == "lift"
    # the imprint (case / clean) is a gain of about 0.88 on one branch and 1.12 on the other:
    assert entry["params"]["rising_gain"] == pytest.approx(0.88, abs=0.04)
    assert 0.15 < entry["params"]["magnitude"] < 0.35                        # 1.12 / 0.88 - 1 = 0.27
    assert min(row["recovered"].values()) >= 0.5


def assert_mix_named(model: Path, clean_rmse: dict, cases: tuple[str, ...], names: list[str]) -> dict:
    """The diagnosis of ``cases`` composed into one (:func:`benchmarks.independent_plant.compose`)
    accepts exactly ``names`` (sorted) and is right; its report."""
    mix = compose(DEFAULT_DATA, cases, model.parent / "mixes")
    row, report = run_case(model, clean_rmse, mix)
    assert sorted(row["accepted"]) == names
    assert row["right"], row
    return report


def test_a_hysteresis_and_a_pickup_together_are_both_named(model, clean_rmse):
    assert_mix_named(model, clean_rmse, ("hysteresis", "mains"), ["hysteresis", "periodic_disturbance"])


def test_a_drift_and_a_pickup_together_are_both_named(model, clean_rmse):
    """A mix the set does not show, composed exactly (both add to the measured lift): clean plus
    the drift case's and the mains case's departures from it (one noise seed for all cases)."""
    assert_mix_named(model, clean_rmse, ("drift", "mains"), ["periodic_disturbance", "zero_drift"])


def test_a_resonance_and_a_pickup_together_are_both_named(model, clean_rmse):
    """Exact (the pickup adds to the measured lift after the balance's mode): the mode is fitted
    where it is (31 Hz, lightly damped) although the 60 Hz line stands far higher above the print."""
    report = assert_mix_named(model, clean_rmse, ("resonance", "mains"), ["periodic_disturbance", "sensor_resonance"])
    mode = next(e for e in report["effects"] if e["name"] == "sensor_resonance")
    assert mode["params"]["damping_ratio"] == pytest.approx(0.05, rel=0.3)


def test_a_resonance_and_a_drift_together_are_both_named(model, clean_rmse):
    assert_mix_named(model, clean_rmse, ("resonance", "drift"), ["sensor_resonance", "zero_drift"])


def test_a_hysteresis_of_half_the_size_is_confirmed_at_the_lower_bar(model, clean_rmse):
    """Another parameter of the same plant: the case's imprint (case − clean, one noise seed)
    halved. Its held-out gain is significant at t ≥ 2 but not at t ≥ 3; its evidence on the
    training record departs from the fingerprint, so the held-out records only need to confirm it."""
    case = compose(DEFAULT_DATA, ("hysteresis",), model.parent / "scaled", 0.5)
    row, report = run_case(model, clean_rmse, case)
    assert row["accepted"] == ["hysteresis"] and row["right"], row
    entry = next(e for e in report["effects"] if e["name"] == "hysteresis")
    assert "departs from the fingerprint" in entry["evidence"]


def test_the_hysteresis_is_right_when_a_renamed_random_record_trains(model, clean_rmse, tmp_path):
    """A user's form: the records renamed (run_a = random, run_b = sine_k025, run_c = sine_k0125),
    training on run_a, which repeats no identification input. Its reference is predicted from its
    input, and the hysteresis is kept on its play operator's branch (the Cμ-direction test alone,
    t = −3.1, misses a hysteresis that follows the lift on a random input); it recovers more than
    half of the error it added on both sines (69 % and 87 % measured)."""
    import shutil


    folders = {}
    for case in ("hysteresis", "clean"):
        d = tmp_path / case
        d.mkdir()
        for new, old in (("run_a", "random"), ("run_b", "sine_k025"), ("run_c", "sine_k0125")):
            shutil.copy(DEFAULT_DATA / case / f"{old}.csv", d / f"{new}.csv")
        folders[case] = d
    out = tmp_path / "out"
    d = folders["hysteresis"]
    run_cli("diagnose", "--model", model, "--train", d / "run_a.csv", "--validate", d / "run_b.csv",
            d / "run_c.csv", "--out", out)
    report = json.loads((out / "report.json").read_text())
    assert report["references"]["run_a"]["source"] == "predicted"
    assert report["references"]["run_c"]["source"] == "repeat"
    assert report["references"]["run_b"]["source"] == "predicted"

    def rmse(model_file, folder, name):
        run_cli("validate", "--model", model_file, folder / "run_b.csv", folder / "run_c.csv", "--json",
                tmp_path / name)
        return {k: v["rmse"] for k, v in json.loads((tmp_path / name).read_text())["records"].items()}

    row = judge_case("hysteresis", report, json.loads((DEFAULT_DATA / "hysteresis" / "truth.json").read_text()),
                     rmse(model, d, "m.json"), rmse(out / "model_augmented.json", d, "a.json"),
                     rmse(model, folders["clean"], "c.json"), scored=("run_b", "run_c"))
    assert row["accepted"] == ["hysteresis"]
    assert row["recovered"]["run_b"] == pytest.approx(0.69, abs=0.15)
    assert row["recovered"]["run_c"] == pytest.approx(0.87, abs=0.15)
    assert row["right"]


@pytest.fixture(scope="module")
def trains_model(tmp_path_factory) -> Path:
    return identified_copy(tmp_path_factory, "ip_trains", trains=True)


@pytest.fixture(scope="module")
def trains_clean_rmse(trains_model) -> dict:
    return validate(trains_model, DEFAULT_DATA / "clean", trains_model.parent / "clean.json")


@pytest.mark.parametrize("case", ["clean", "delay", "resonance", "fade", "drift", "mains", "hysteresis",
                                  "delay_mains"])
def test_the_case_is_diagnosed_right_with_a_model_identified_with_the_trains(trains_model, trains_clean_rmse, case):
    """Issue 31: the same protocol on the interaction model ``rtlift identify`` chooses for the full
    campaign: all eight cases right, as with the paper's hybrid (the fade since its stage goes before
    the structure's ``delivered_envelope``, the hysteresis since its lift driver is the flow's whole
    slow lift, docs/results/bursts.md)."""
    row, _ = run_case(trains_model, trains_clean_rmse, case)
    assert row["right"], row


def test_the_hysteresis_on_the_trains_model_is_driven_by_the_flows_whole_slow_lift(trains_model, trains_clean_rmse):
    """The interaction model carries about half of its static lift in the burst part's slow term:
    with the Wiener part alone as the driver the fit took a play operator on the Wiener input for
    it and recovered nothing on random (the case was missed). Measured: width 0.10 (ΔCL), rising
    gain 0.59, magnitude 0.94 (on the Wiener part alone: the factor scales about half the lift, so
    the magnitude is about twice the hybrid's 0.23); recovered 98 % and 61 %."""
    row, report = run_case(trains_model, trains_clean_rmse, "hysteresis")
    assert row["accepted"] == ["hysteresis"] and row["right"], row
    entry = next(e for e in report["effects"] if e["name"] == "hysteresis")
    assert entry["kind"] == "effect" and entry["params"]["driver"] == "lift"
    assert 0.4 < entry["params"]["magnitude"] < 1.5
    assert min(row["recovered"].values()) >= 0.5


def run_field_case(model: Path, case: str) -> dict:
    """The README's user form of ``case`` on ``model``: the records renamed run_a/b/c, training on
    run_a (``random``), the two sines validating; the row :func:`judge_case` gives."""
    work = model.parent / "field"
    clean = validate(model, anonymize(DEFAULT_DATA / "clean", work / "clean"), work / "clean.json",
                     FIELD_SCORED, FIELD_NAMES)
    d = anonymize(DEFAULT_DATA / case, work / case)
    out = work / f"{case}_out"
    run_cli("diagnose", "--model", model, "--train", d / f"{FIELD_NAMES[FIELD_TRAIN]}.csv",
            "--validate", *(d / f"{FIELD_NAMES[r]}.csv" for r in FIELD_SCORED), "--out", out)
    report = json.loads((out / "report.json").read_text())
    truth = json.loads((DEFAULT_DATA / case / "truth.json").read_text())
    return judge_case(case, report, truth, validate(model, d, out / "m.json", FIELD_SCORED, FIELD_NAMES),
                      validate(out / "model_augmented.json", d, out / "a.json", FIELD_SCORED, FIELD_NAMES), clean,
                      FIELD_SCORED)


@pytest.mark.parametrize("case", ["clean", "delay", "resonance", "fade", "drift", "mains", "hysteresis",
                                  "delay_mains"])
def test_the_users_form_is_right_on_every_case(model, case):
    """The README's user form on the paper's hybrid (``rtlift identify`` with the README's
    defaults): all eight right since competing explanations are compared on the validation error
    with each record's own mean taken out. Before, the drift was taken for a fade: the hybrid's
    own level misfit differs between record types (clean mean residual +0.0025 on ``random``,
    −0.0057 and −0.0108 on the sines) and a fade, lowering the lift in proportion, corrected it on
    the validating sines (raw validation RMSE fade 0.01301, drift 0.01356; with the means taken
    out 0.00897 and 0.00858)."""
    row = run_field_case(model, case)
    assert row["right"], row


@pytest.mark.parametrize("case", ["clean", "delay", "resonance", "fade", "drift", "mains", "hysteresis",
                                  "delay_mains"])
def test_the_users_form_is_right_on_every_case_with_a_model_identified_with_the_trains(trains_model, case):
    """The same on the interaction model identified with the trains: all eight right. Measured:
    fade f 0.816, delay 22 vs 22, resonance 31.46 vs 31.00 Hz."""
    row = run_field_case(trains_model, case)
    assert row["right"], row


@pytest.mark.parametrize("name", ["delay8", "delay36", "resonance18", "mains50"])
def test_other_parameters_of_the_same_plant_are_right_on_the_papers_hybrid(model, clean_rmse, name):
    """Parameters the set does not show (``benchmarks.independent_plant --variants``): a delay of
    8 or 36 samples, a mode at 18 Hz, 50 Hz pickup, each exactly recovered or nearly (measured:
    delay 100 %, mode 17.79 Hz and 91–93 %, pickup 50.03 Hz and 91 %)."""
    row, _ = run_case(model, clean_rmse, variant(DEFAULT_DATA, name, model.parent / "variants"))
    assert row["right"], row


@pytest.mark.parametrize("name", ["drift_fast", "ramp"])
def test_a_positive_drift_is_found_with_the_full_campaigns_model(trains_model, trains_clean_rmse, name):
    """A drift of +0.02 approached with τ 5 s, and a ramp of 5e-4 per second: found with the model
    the full campaign identifies (its level misfit within 0.003 on every record type), while the
    paper's hybrid misses both (its own level misfit on ``sine_k025``, −0.011, cancels a positive
    drift there: docs/RESULTS.md). Measured: recovered 105 % and 99 %; the ramp 80 % on ``random``."""
    row, _ = run_case(trains_model, trains_clean_rmse, variant(DEFAULT_DATA, name, trains_model.parent / "variants"))
    assert row["accepted"] == ["zero_drift"] and row["right"], row

"""``rtlift diagnose`` end to end: files written, schema of INTERFACES.md, augmented model loads."""

from __future__ import annotations

import json

import pytest

from hil_sim.experiments import run_experiment, write_bench_record
from rtlift.app.cli import main
from rtlift.model.modelfile import load_model, model_from_dict, save_model
from tests.test_observer_bench import _identified
from tests.test_sysid import tanks_case


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    save_model(model_from_dict(_identified()), d / "model.json")   # the clean campaign (seed 1), identified once
    effect = ["periodic_disturbance:frequency_hz=20,amplitude=0.01"]
    write_bench_record(run_experiment("sine_k0125", seed=21, effects=effect), d / "train.csv")
    write_bench_record(run_experiment("sine_k0125", seed=22, effects=effect), d / "val.csv")
    write_bench_record(run_experiment("random", seed=23, effects=effect), d / "valr.csv")
    return d


@pytest.fixture(scope="module")
def diagnosed(files):
    """``rtlift diagnose`` of the model on train, validated on val and valr: its output folder
    (the same command for the first two tests; it is deterministic, issue 26)."""
    out = files / "out"
    assert main(["diagnose", "--model", str(files / "model.json"), "--train", str(files / "train.csv"),
                 "--validate", str(files / "val.csv"), str(files / "valr.csv"), "--out", str(out)]) == 0
    return out


def test_diagnose_writes_the_report_the_figures_and_a_loadable_augmented_model(files, diagnosed):
    out = diagnosed
    rep = json.loads((out / "report.json").read_text())
    assert {"version", "baseline", "augmented", "effects", "unexplained"} <= set(rep)
    assert rep["version"] == 1 and set(rep["baseline"]["records"]) == {"train", "val", "valr"}
    for scores in (*rep["baseline"]["records"].values(), *rep["augmented"]["records"].values()):
        assert set(scores) == {"corr", "nrmse", "rmse"}
    for e in rep["effects"]:
        assert set(e) == {"name", "kind", "accepted", "params", "evidence", "validation_rmse_before",
                          "validation_rmse_after"}
        assert e["kind"] in ("effect", "structure")
        assert "\n" not in e["evidence"]
    acc = [e for e in rep["effects"] if e["accepted"]]
    assert [(e["name"], e["kind"]) for e in acc] == [("periodic_disturbance", "effect")]
    assert acc[0]["params"]["frequency_hz"] == pytest.approx(20.0, abs=0.01)
    model = load_model(out / "model_augmented.json")
    assert [s.name for s in model.output_stages] == ["periodic_disturbance"]
    scored = files / "validate.json"
    assert main(["validate", "--model", str(out / "model_augmented.json"), str(files / "val.csv"),
                 str(files / "valr.csv"), "--json", str(scored)]) == 0
    for name, s in json.loads(scored.read_text())["records"].items():    # one scoring: validate = diagnose
        for key in ("corr", "nrmse", "rmse"):
            assert s[key] == pytest.approx(rep["augmented"]["records"][name][key], rel=1e-12, abs=1e-15)
    md = (out / "report.md").read_text()
    for fig in ("residual_time", "residual_spectrum", "residual_autocorr"):
        assert (out / "figures" / f"{fig}.png").stat().st_size > 1000
        assert f"figures/{fig}.png" in md
    assert "RMSE" in md and "NRMSE" in md



def test_the_report_says_per_record_what_it_was_compared_with_from_its_input(diagnosed):
    """The records are named train, val, valr: nothing in a name says what they are. train and val
    repeat the campaign's sine input bit for bit; valr (random) matches no identification input and
    is compared with the residual predicted for its input."""
    out = diagnosed
    refs = json.loads((out / "report.json").read_text())["references"]
    assert set(refs) == {"train", "val", "valr"}
    for name in ("train", "val"):
        assert (refs[name]["source"], refs[name]["entry"], refs[name]["distance"]) == ("repeat", "sine_k0125", 0.0)
    assert refs["valr"]["source"] == "predicted" and refs["valr"]["entry"] is None
    assert refs["valr"]["distance"] > 1.0
    for ref in refs.values():
        assert set(ref) == {"source", "entry", "nearest", "distance", "text"} and "\n" not in ref["text"]
    md = (out / "report.md").read_text()
    assert "## What each record is compared with" in md and "| valr | predicted |" in md

def test_bad_input_is_a_one_line_error_with_status_2(files, tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,cmu,cmu_envelope\n0,0,0\n")
    rc = main(["diagnose", "--model", str(files / "model.json"), "--train", str(bad),
               "--validate", str(files / "val.csv"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    rc = main(["diagnose", "--model", str(files / "model.json"), "--train", str(files / "train.csv"),
               "--validate", str(files / "train.csv"), "--out", str(tmp_path / "o")])
    assert rc == 2


def test_a_lift_and_a_generic_report_have_the_same_keys_written_by_one_writer(files, tmp_path):
    """One report for both model kinds: report.json's top-level keys, its selection's and its
    combinations' are the same; what a generic model cannot have is null; both reports have the
    residual test table and the residual figures."""
    lift, gen = tmp_path / "lift", tmp_path / "gen"
    assert main(["diagnose", "--model", str(files / "model.json"), "--train", str(files / "train.csv"),
                 "--validate", str(files / "val.csv"), "--out", str(lift)]) == 0
    model, est, val = tanks_case(tmp_path)
    assert main(["diagnose", "--model", str(model), "--train", str(est), "--validate", str(val), "--skip", "50",
                 "--out", str(gen)]) == 0
    a, b = (json.loads((d / "report.json").read_text()) for d in (lift, gen))
    assert list(a) == list(b)
    assert set(a["selection"]) == set(b["selection"]) == {"rule", "pool", "chosen", "combinations"}
    rows = [*a["selection"]["combinations"], *b["selection"]["combinations"]]
    assert rows and all(set(c) == {"members", "parameters", "validation_rmse", "level_free_rmse", "admissible", "why"}
                        for c in rows)
    assert all(c["level_free_rmse"] <= c["validation_rmse"] for c in rows)
    assert [c["members"] for c in b["selection"]["combinations"]] == [[n] for n in b["selection"]["pool"]]
    assert b["selection"]["pool"] == ["output_dynamics", "nonlinear_feedback", "saturation"]
    assert b["selection"]["chosen"] == [e["name"] for e in b["effects"] if e["accepted"]]
    assert (b["references"], b["reestimation"], a["not_built"]) == (None, None, None)
    assert b["not_built"] == [] and "no fingerprint" in b["fingerprint"] and b["fit_target"]
    for rep in (a, b):
        for scores in (*rep["baseline"]["records"].values(), *rep["augmented"]["records"].values()):
            assert set(scores) == {"corr", "nrmse", "rmse"}
    for d in (lift, gen):
        md = (d / "report.md").read_text()
        assert "## Residual tests on" in md and "## Competing explanations" in md and "| level-free |" in md
        for fig in ("residual_time", "residual_spectrum", "residual_autocorr"):
            assert (d / "figures" / f"{fig}.png").stat().st_size > 1000 and f"figures/{fig}.png" in md
        assert set(json.loads((d / "residual_tests.json").read_text())) >= {"before", "after", "combinations"}
    assert "## What each record is compared with" not in (gen / "report.md").read_text()

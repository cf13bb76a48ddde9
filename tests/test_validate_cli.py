"""``rtlift validate``: per-record ρ, NRMSE, RMSE as INTERFACES.md's JSON, and figures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil_sim.experiments import run_experiment
from rtlift.app.cli import main
from rtlift.core.metrics import scores
from rtlift.core.records import read_record, write_record
from rtlift.model.modelfile import load_model
from tests.test_identify_cli import campaign_model


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """The model ``rtlift identify`` writes for the bench's seed-1 campaign (the one
    tests/test_identify_cli.py checks, identified once per run), validated on seed-2 records it
    never saw."""
    d = tmp_path_factory.mktemp("validate")
    paths = {}
    for name in ("sine_k0125", "random"):
        paths[name] = d / f"{name}.csv"
        write_record(paths[name], run_experiment(name, seed=2).to_record())
    return d, paths, campaign_model()


def test_validate_json_has_exactly_the_interface_keys(setup, tmp_path):
    _, paths, model = setup
    out = tmp_path / "v.json"
    assert main(["validate", "--model", str(model), str(paths["sine_k0125"]),
                 str(paths["random"]), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc) == {"version", "model", "records"}
    assert doc["version"] == 1 and doc["model"] == str(model)
    assert set(doc["records"]) == {"sine_k0125", "random"}
    for rec in doc["records"].values():
        assert set(rec) == {"corr", "nrmse", "rmse"}


def test_validate_scores_are_the_open_loop_model_against_the_measurement(setup, tmp_path):
    _, paths, model = setup
    out = tmp_path / "v.json"
    assert main(["validate", "--model", str(model), str(paths["random"]), "--json", str(out)]) == 0
    got = json.loads(out.read_text())["records"]["random"]
    rec = read_record(paths["random"])
    m = load_model(model)
    expect = scores(rec.dcl, m.simulate(rec.cmu, rec.cmu_envelope).total)
    for k in ("corr", "nrmse", "rmse"):
        assert got[k] == pytest.approx(expect[k], rel=1e-12)
    assert got["corr"] > 0.9277                             # the paper's random-actuation ρ


def test_validate_writes_one_figure_per_record_and_a_summary(setup, tmp_path, capsys):
    _, paths, model = setup
    figs = tmp_path / "figs"
    assert main(["validate", "--model", str(model), str(paths["sine_k0125"]),
                 str(paths["random"]), "--figures", str(figs)]) == 0
    assert sorted(p.name for p in figs.iterdir()) == ["random.png", "sine_k0125.png"]
    assert all(p.stat().st_size > 10_000 for p in figs.iterdir())
    out = capsys.readouterr().out
    assert "sine_k0125" in out and "random" in out and "corr" in out


def test_validate_refuses_an_unstable_model_with_exit_2(setup, tmp_path, capsys):
    _, paths, model = setup
    d = json.loads(model.read_text())
    d["wiener"]["A"] = [[1.9960, -0.9960], [1.0, 0.0]]     # the paper's printed matrices
    d["wiener"]["B"] = [1.0, 0.0]
    d["wiener"]["C"] = [0.0003288, -0.0003276]
    bad = tmp_path / "paper.json"
    bad.write_text(json.dumps(d))
    assert main(["validate", "--model", str(bad), str(paths["random"])]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_validate_rejects_a_record_at_another_sample_rate(setup, tmp_path, capsys):
    _, paths, model = setup
    rec = read_record(paths["random"])
    rec.meta["fs_hz"] = "200"
    rec.t = np.arange(len(rec)) / 200.0
    other = tmp_path / "slow.csv"
    write_record(other, rec)
    assert main(["validate", "--model", str(model), str(other)]) == 2
    assert "200" in capsys.readouterr().err

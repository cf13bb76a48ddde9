"""``rtlift identify``: records in, a loadable model file with provenance and metrics out."""

from __future__ import annotations

import json

import pytest

from hil_sim.experiments import run_experiment
from rtlift.app.cli import main
from rtlift.core.records import write_record
from rtlift.model.modelfile import load_model


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("campaign")
    paths = {}
    for name in ("static", "single_burst", "sine_k0125"):
        paths[name] = d / f"{name}.csv"
        write_record(paths[name], run_experiment(name, seed=1).to_record())
    return d, paths


def identify_args(paths, out, *extra):
    return ["identify", "--static", str(paths["static"]), "--single-burst",
            str(paths["single_burst"]), "--train", str(paths["sine_k0125"]), "-o", str(out), *extra]


@pytest.fixture(scope="module")
def model_file(campaign):
    d, paths = campaign
    out = d / "model.json"
    assert main(identify_args(paths, out)) == 0
    return out


def test_identify_writes_a_model_that_loads_and_is_stable(model_file):
    m = load_model(model_file)
    assert m.fs_hz == 400.0
    assert m.stable
    structure = json.loads(model_file.read_text())["provenance"]["structure"]
    assert {"input_gain": "input_gain", "output_map": "output"}[structure["form"]] == m.wiener.nonlinearity.form
    assert len(structure["candidates"]) == 2 * 9            # both forms x dead times 0..8, by held-out RMSE
    chosen = [c for c in structure["candidates"] if c["form"] == structure["form"]
              and c["dead_time_samples"] == structure["dead_time_samples"]]
    assert chosen[0]["holdout_rmse"] <= 1.01 * min(c["holdout_rmse"] for c in structure["candidates"])
    assert [s.name for s in m.input_stages] == (["delay"] if structure["dead_time_samples"] else [])
    assert structure["name"] == "paper" and structure["choice"]["chosen"] == "paper"    # no trains given
    assert "no burst-train records" in structure["choice"]["why"]


def test_model_file_records_hpf_phi_orders_uncertainty_and_observer_hints(model_file):
    d = json.loads(model_file.read_text())
    p, met = d["provenance"], d["metrics"]
    assert p["fs_hz"] == 400.0
    assert p["highpass"]["order"] == d["highpass"]["order"]
    assert p["highpass"]["cutoff_hz"] == d["highpass"]["cutoff_hz"]
    assert p["phi"] == pytest.approx(d["convolution"]["phi"])
    assert p["wiener"]["order"] == len(d["wiener"]["C"])
    assert len(p["wiener"]["order_selection"]["candidates"]) == 4
    unc = p["wiener"]["uncertainty"]
    assert len(unc["a_std"]) == p["wiener"]["order"] and unc["dc_gain_std"] > 0
    assert p["static_map"]["hysteresis"]["verdict"]
    assert 0 < met["residual_std_train"] < 0.02
    assert 0 < met["measurement_noise_std"] < met["residual_std_train"] * 2
    assert met["train"]["corr"] > 0.97
    assert d["observer"]["model_residual_std"] == met["residual_std_train"]


def test_order_option_fixes_the_wiener_order(campaign, tmp_path, capsys):
    _, paths = campaign
    out = tmp_path / "m3.json"
    assert main(identify_args(paths, out, "--order", "3", "--phi", "single_burst")) == 0
    d = json.loads(out.read_text())
    assert len(d["wiener"]["A"]) == 3
    assert d["provenance"]["phi_choice"]["used"] == "single_burst"
    assert "order 3" in capsys.readouterr().out


def test_textbook_wiener_form_stores_the_static_map_as_f_of_y(campaign, tmp_path):
    _, paths = campaign
    out = tmp_path / "tb.json"
    assert main(identify_args(paths, out, "--form", "output_map", "--order", "1")) == 0
    assert load_model(out).wiener.nonlinearity.form == "output"


def test_bad_record_is_a_one_line_error_with_exit_2(campaign, tmp_path, capsys):
    _, paths = campaign
    bad = tmp_path / "bad.csv"
    bad.write_text("t,cmu,dcl\n0,0,0\n")
    args = identify_args(paths, tmp_path / "x.json")
    args[args.index("--train") + 1] = str(bad)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cmu_envelope" in err


def test_record_without_bursts_is_a_one_line_error_with_exit_2(campaign, tmp_path, capsys):
    _, paths = campaign
    args = identify_args(paths, tmp_path / "x.json")
    args[args.index("--single-burst") + 1] = str(paths["static"]).replace("static", "sine_k0125")
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("rtlift: error:")


def test_a_stage_that_makes_a_nan_stops_identify_with_one_line_naming_it(campaign, tmp_path, monkeypatch, capsys):
    """Issue 26: a non-finite number is caught where it arises, not by the JSON writer: exit 1,
    one line naming the stage and the record, no model file and no temporary file left."""
    import numpy as np

    from rtlift.identify import campaign as stages

    real = stages.fit_kernel

    def poisoned(*args, **kwargs):
        k = real(*args, **kwargs)
        k.kernel[3] = np.nan
        return k

    monkeypatch.setattr(stages, "fit_kernel", poisoned)
    _, paths = campaign
    out = tmp_path / "m.json"
    assert main(identify_args(paths, out)) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"rtlift: error: single-burst kernel on {paths['single_burst'].stem}: kernel[3] is not finite "
                   "(NaN or Inf); nothing was written"]
    assert list(tmp_path.iterdir()) == []


def test_a_model_file_is_written_whole_or_not_at_all(model_file, tmp_path):
    from rtlift.core.errors import NumericalError
    from rtlift.model.modelfile import save_model

    m = load_model(model_file)
    m.provenance["wiener"]["uncertainty"]["poles_std"] = [0.1, float("inf")]
    out = tmp_path / "m.json"
    with pytest.raises(NumericalError, match=r"provenance\.wiener\.uncertainty\.poles_std\[1\] is not finite"):
        save_model(m, out)
    assert list(tmp_path.iterdir()) == []

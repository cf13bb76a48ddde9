"""``rtlift identify``: records in, a loadable model file with provenance and metrics out."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rtlift.app.cli import main
from rtlift.model.modelfile import load_model
from testkit.shared import bench_records, identified

CAMPAIGN = ("static", "single_burst", "sine_k0125")


def campaign_records() -> dict:
    """The bench's seed-1 campaign, written once per test run (read-only; tests/test_validate_cli.py
    identifies on the same files)."""
    return bench_records(1, CAMPAIGN)


@pytest.fixture(scope="module")
def campaign():
    paths = campaign_records()
    return paths["static"].parent, paths


def campaign_args(paths) -> list[str]:
    return ["--static", str(paths["static"]), "--single-burst", str(paths["single_burst"]),
            "--train", str(paths["sine_k0125"])]


def identify_args(paths, out, *extra):
    return ["identify", *campaign_args(paths), "-o", str(out), *extra]


def campaign_model() -> Path:
    """What ``rtlift identify`` with defaults writes for :func:`campaign_records` (read-only),
    computed once per test run for this module and tests/test_validate_cli.py
    (:func:`testkit.shared.identified`: the same command on the same files)."""
    return identified(*campaign_args(campaign_records()))


@pytest.fixture(scope="module")
def model_file(campaign):
    return campaign_model()


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


def test_envelope_option_makes_the_wiener_input_what_the_bursts_delivered(campaign, tmp_path, capsys):
    _, paths = campaign
    out = tmp_path / "delivered.json"
    assert main(identify_args(paths, out, "--envelope", "delivered", "--order", "1", "--phi", "single_burst")) == 0
    m = load_model(out)
    assert [s.name for s in m.input_stages][-1] == "onset_hold"
    assert json.loads(out.read_text())["provenance"]["structure"]["envelope"].startswith("delivered")
    assert "Wiener input: the envelope delivered" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(identify_args(paths, tmp_path / "x.json", "--envelope", "held"))
    assert exc.value.code == 2 and "invalid choice: 'held'" in capsys.readouterr().err


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


def test_diagnose_takes_several_training_records_of_a_generic_system(tmp_path, capsys):
    """``rtlift diagnose --train A --train B`` (issue 48): a tanh between two first-order blocks,
    A at a small amplitude (nearly linear), B and the validation record C at ten times it; the
    Wiener model identified on A. Trained on A alone, no structure passes (C: RMSE 1.06); on A and B
    (each its own run from rest, one cost) the added output block is fitted where C lives (C: 0.06,
    the augmented model's provenance names both). One record given as a list of one is the
    single-record diagnosis, number for number."""
    from dataclasses import replace
    from unittest import mock

    import numpy as np
    from scipy import signal

    from rtlift import api
    from rtlift.core.records import SisoRecord, write_siso_record
    from rtlift.diagnose import report
    from rtlift.sysid import identify as sysid_identify
    from rtlift.sysid.common import SisoOptions

    fast = replace(SisoOptions(), orders=(2,), knots=8, more_knots=(), max_nfev=30, keep=1, feedback_orders=(2,),
                   chain_starts=1, skip=20)
    rng = np.random.default_rng(1)
    for name, amp in (("a", 0.3), ("b", 3.0), ("c", 3.0)):
        u = amp * np.repeat(rng.standard_normal(100), 4)
        y = signal.lfilter([0.4], [1, -0.6], np.tanh(signal.lfilter([0.3], [1, -0.7], u)))
        write_siso_record(tmp_path / f"{name}.csv", SisoRecord(np.arange(u.size) / 10.0, u,
                                                               y + 0.01 * rng.standard_normal(u.size), {}, name))
    rec = {n: str(tmp_path / f"{n}.csv") for n in "abc"}
    model = str(tmp_path / "m.json")
    with (mock.patch.object(sysid_identify, "SisoOptions", lambda: fast),
          mock.patch.object(report, "plot", lambda diag, out, fs: report._fig_paths(out))):
        assert main(["identify", "--record", rec["a"], "--structure", "wiener", "-o", model]) == 0
        runs = {}
        for tag, trains in (("one", "a"), ("two", "ab")):
            assert main(["diagnose", "--model", model, *(x for t in trains for x in ("--train", rec[t])),
                         "--validate", rec["c"], "--out", str(tmp_path / tag), "--quiet"]) == 0
            runs[tag] = (json.loads((tmp_path / tag / "report.json").read_text()),
                         json.loads((tmp_path / tag / "model_augmented.json").read_text()))
        listed, _ = api.diagnose(model, [rec["a"]], [rec["c"]])
    capsys.readouterr()
    (one, _), (two, augmented) = runs["one"], runs["two"]
    assert list(one["augmented"]["records"]) == ["a", "c"] and list(two["augmented"]["records"]) == ["a+b", "c"]
    before, after_one, after_two = (r["records"]["c"]["rmse"] for r in (one["baseline"], one["augmented"],
                                                                         two["augmented"]))
    assert not any(e["accepted"] for e in one["effects"]) and after_one == before
    assert [e["name"] for e in two["effects"] if e["accepted"]] == ["output_dynamics"]
    assert augmented["provenance"]["records"] == ["a", "b"] and after_two < 0.2 * before, (after_two, before)
    feedback = next(e for e in two["effects"] if e["name"] == "nonlinear_feedback")
    assert "identified from one record" in feedback["evidence"] or "identified from one record" in str(feedback)
    assert listed["augmented"]["records"] == one["augmented"]["records"]
    assert listed["baseline"]["records"] == one["baseline"]["records"]

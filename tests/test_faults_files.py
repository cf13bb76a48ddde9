"""Fault matrix, bad input files and values: malformed record CSV, model and calibration
files, an unstable or wrongly shaped model, a model without observer settings, a corrupt
log, a NaN measurement. Every file row: exit status 2 and one line on stderr naming the
file and the problem — never a traceback, never an internal error."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from rtlift.model.modelfile import load_model
from rtlift.observer import FLAG_BAD_INPUT, FLAG_MISSING, Observer
from tests.test_faults_support import rtlift, write_model

PAPER_MODEL = Path(__file__).resolve().parents[1] / "rtlift" / "data" / "paper_model.json"
RECORD = "t,cmu,cmu_envelope,dcl\n" + "".join(f"{k / 400!r},0.0,0.001,0.01\n" for k in range(400))


def message(run) -> str:
    """The error line without the prefix and the directory of the files."""
    return re.sub(r"(?<!\S)/\S*/", "", run.err[0].removeprefix("rtlift: error: "))


def assert_one_line_error(run, *words: str) -> None:
    assert run.code == 2, run.err
    assert not run.traceback and len(run.err) == 1 and run.err[0].startswith("rtlift: error: "), run.err
    for w in words:
        assert w in run.err[0], run.err


@pytest.fixture
def model(tmp_path) -> Path:
    return write_model(tmp_path / "model.json")


@pytest.mark.parametrize("text,words", [
    (RECORD.replace("cmu_envelope,", ""), ("rec.csv:1", "'cmu_envelope' is missing")),
    (RECORD.replace("0.0,0.001,0.01\n", "0.0,0.001,abc\n", 1), ("rec.csv:2", "'dcl'", "not a number")),
    (RECORD.replace("0.0,0.001,0.01\n", "0.0,0.001,nan\n", 1), ("rec.csv:2", "not a finite number")),
    (RECORD.replace("0.0025,", "0.0,", 1), ("rec.csv:3", "'t'", "not strictly increasing")),
    (RECORD + "1.0,0.0\n", ("rec.csv:402", "2 cells, the header has 4")),
], ids=["missing_column", "non_numeric", "nan", "t_not_increasing", "short_row"])
def test_malformed_csv(tmp_path, capsys, model, record_property, text, words):
    """A record CSV with a missing column, a non-numeric or NaN cell, a non-increasing t or a
    short row: exit 2, one line naming file, line and column."""
    rec = tmp_path / "rec.csv"
    rec.write_text(text)
    run = rtlift(capsys, "validate", "--model", str(model), str(rec))
    assert_one_line_error(run, *words)
    record_property("measured", f"exit {run.code}: {message(run)}")


@pytest.mark.parametrize("mutate,words", [
    (lambda text: text[: len(text) // 2], ("not valid JSON",)),
    (lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "wiener"}), ("missing key 'wiener'",)),
    (lambda text: text.replace('"rtlift-model"', '"other-model"'), ("not an rtlift model file",)),
], ids=["truncated_json", "missing_key", "wrong_format"])
def test_malformed_model_file(tmp_path, capsys, model, record_property, mutate, words):
    """A model file cut short, missing a section or of another format: exit 2, one line."""
    model.write_text(mutate(model.read_text()))
    rec = tmp_path / "rec.csv"
    rec.write_text(RECORD)
    run = rtlift(capsys, "validate", "--model", str(model), str(rec))
    assert_one_line_error(run, "model.json", *words)
    record_property("measured", f"exit {run.code}: {message(run)}")


@pytest.mark.parametrize("text,words", [
    ("alpha_deg = \n", ("not valid TOML",)),
    ("chord_m = -0.2\n", ("chord_m must be positive",)),
    ("wingspan = 1.0\n", ("unknown calibration key 'wingspan'",)),
    ("matrix = [[1, 0], [0, 1]]\n", ("6x6",)),
], ids=["not_toml", "negative_chord", "unknown_key", "matrix_shape"])
def test_malformed_calibration_file(tmp_path, capsys, model, record_property, text, words):
    """A calibration file that is not TOML, has a non-physical value, an unknown key or a
    matrix of the wrong shape: exit 2, one line, before any device is touched."""
    cal = tmp_path / "cal.toml"
    cal.write_text(text)
    run = rtlift(capsys, "observe", "--serial", str(tmp_path / "no-such-port"), "--model", str(model),
                 "--calibration", str(cal), "--seconds", "1")
    assert_one_line_error(run, "cal.toml", *words)
    record_property("measured", f"exit {run.code}: {message(run)}")


def test_unstable_model(tmp_path, capsys, record_property):
    """The paper's printed model (an eigenvalue of A at 1) is refused: exit 2, one line with
    the spectral radius; it would integrate a step without bound inside the observer."""
    rec = tmp_path / "rec.csv"
    rec.write_text(RECORD)
    run = rtlift(capsys, "replay", str(rec.with_suffix(".bin")), "--model", str(PAPER_MODEL))
    assert_one_line_error(run, "paper_model.json", "not stable", "spectral radius")
    run_v = rtlift(capsys, "validate", "--model", str(PAPER_MODEL), str(rec))
    assert_one_line_error(run_v, "not stable")
    record_property("measured", f"replay and validate exit {run.code}: {message(run).split(';')[0]}")


@pytest.mark.parametrize("part,value,words", [
    ("B", [1.0, 0.0, 0.0], ("shapes do not agree",)),
    ("A", [[0.5, 0.1], [0.2]], ("not an array of numbers",)),
    ("C", [[1.0, 2.0]], ("expected 1-D array",)),
], ids=["B_length", "ragged_A", "C_matrix"])
def test_wrong_shape_model(tmp_path, capsys, model, record_property, part, value, words):
    """A Wiener block whose A, B, C do not fit together: exit 2, one line."""
    d = json.loads(model.read_text())
    d["wiener"][part] = value
    model.write_text(json.dumps(d))
    run = rtlift(capsys, "replay", str(tmp_path / "run.bin"), "--model", str(model))
    assert_one_line_error(run, "model.json", *words)
    record_property("measured", f"exit {run.code}: {message(run)}")


def test_model_without_observer_settings(tmp_path, capsys, model, record_property):
    """A model file without Q and R cannot drive the observer: exit 2, one line saying how
    to add them."""
    d = json.loads(model.read_text())
    d["observer"] = {}
    model.write_text(json.dumps(d))
    run = rtlift(capsys, "observe", "--serial", str(tmp_path / "no-such-port"), "--model", str(model))
    assert_one_line_error(run, "no observer settings (Q and R)", "tune_observer")
    record_property("measured", f"exit {run.code}: {message(run)}")


@pytest.mark.parametrize("name,content,words", [
    ("run.bin", bytes(range(256)) * 40, ("no samples",)),
    ("run.blf", b"LOGG" + bytes(200), ("run.blf",)),
    ("run.txt", b"x", ("unknown log type",)),
], ids=["garbage_capture", "corrupt_blf", "unknown_type"])
def test_malformed_log_file(tmp_path, capsys, model, record_property, name, content, words):
    """A capture that holds no valid packet, a corrupt BLF, an unknown log type: exit 2, one line."""
    log = tmp_path / name
    log.write_bytes(content)
    run = rtlift(capsys, "replay", str(log), "--model", str(model))
    assert_one_line_error(run, *words)
    record_property("measured", f"exit {run.code}: {message(run)}")


def test_nan_measurement(model, record_property):
    """Through the Python API a NaN or infinite ΔCL is predict-only (counted missing): the
    state stays finite and the next real measurement is used as usual."""
    obs = Observer.from_model(load_model(model))
    ref = Observer.from_model(load_model(model))
    rng = np.random.default_rng(5)
    z = 0.05 + 0.02 * rng.standard_normal(400)
    for k in range(400):
        bad = k in (100, 200, 300)
        est = obs.step(0.0, 0.01, (math.nan if k < 250 else math.inf) if bad else float(z[k]))
        ref_est = ref.step(0.0, 0.01, None if bad else float(z[k]))
        assert math.isfinite(est.dcl) and est.dcl == ref_est.dcl
        assert bool(est.flags & FLAG_MISSING) == bad
    assert obs.monitors()["missing"] == 3 and np.all(np.isfinite(obs.get_state()))
    record_property("measured", f"3 non-finite ΔCL: missing {obs.monitors()['missing']}, estimates identical to "
                                "'no measurement', state finite")


def test_nan_input(model, record_property):
    """Through the Python API a NaN or infinite Cμ or Cμ_env holds the last finite inputs and
    is predict-only (FLAG_BAD_INPUT, counted): the model's state stays finite for good."""
    obs = Observer.from_model(load_model(model))
    ref = Observer.from_model(load_model(model))
    rng = np.random.default_rng(6)
    env = 0.011 + 0.005 * np.sin(np.arange(400) / 40)
    z = 0.05 + 0.01 * rng.standard_normal(400)
    for k in range(400):
        bad = k in (120, 220, 320)
        c, e = (math.nan, env[k]) if k == 120 else (env[k], math.inf) if k == 220 else \
            (math.nan, math.nan) if k == 320 else (env[k], env[k])
        est = obs.step(c, e, float(z[k]))
        ref_est = ref.step(env[k - 1], env[k - 1], None) if bad else ref.step(env[k], env[k], float(z[k]))
        assert math.isfinite(est.dcl) and est.dcl == ref_est.dcl
        assert bool(est.flags & FLAG_BAD_INPUT) == bad
    assert obs.monitors()["bad_inputs"] == 3 and np.all(np.isfinite(obs.get_state()))
    record_property("measured", f"3 non-finite inputs: bad_inputs {obs.monitors()['bad_inputs']}, estimates "
                                "identical to holding the last inputs without a measurement, state finite")

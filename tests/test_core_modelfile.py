"""Model file: round trip, validation with one-line errors, and the paper's printed (unstable) model."""

from __future__ import annotations

import json
from importlib.resources import files

import numpy as np
import pytest

from rtlift.blocks.delay import Delay
from rtlift.blocks.lti import LTIBlock, spectral_radius
from rtlift.core.errors import ModelFileError
from rtlift.model.modelfile import load_model, model_to_dict, save_model
from testkit.synthetic import burst_input, make_model

PAPER = files("rtlift") / "data" / "paper_model.json"


def test_round_trip_reproduces_the_model_exactly(tmp_path, rng):
    m = make_model(rng, kernel_len=40)
    m.input_stages = (Delay(0.01, 400.0),)
    save_model(m, tmp_path / "m.json", provenance={"by": "test"}, metrics={"corr": 0.9})
    m2 = load_model(tmp_path / "m.json")
    cmu, env = burst_input(rng, 2000)
    m.reset()
    np.testing.assert_array_equal(m.simulate(cmu, env).total, m2.simulate(cmu, env).total)
    assert m2.provenance == {"by": "test"} and m2.metrics == {"corr": 0.9}
    assert [s.name for s in m2.input_stages] == ["delay"]


def test_papers_printed_A_has_an_eigenvalue_at_exactly_one():
    A = np.array(json.loads(PAPER.read_text())["wiener"]["A"])
    eig = np.sort(np.linalg.eigvals(A).real)
    np.testing.assert_allclose(eig, [0.996, 1.0], atol=1e-12)
    assert spectral_radius(A) == pytest.approx(1.0, abs=1e-12)


def test_papers_printed_model_integrates_a_step_without_bound():
    A = np.array([[1.9960, -0.9960], [1.0, 0.0]])
    lti = LTIBlock(A, [1.0, 0.0], [0.0003288, -0.0003276])
    y = lti.simulate(np.full(40_000, 0.0022))         # 100 s of constant Cμ at 400 Hz
    late, earlier = y[-1] - y[30_000], y[30_000] - y[20_000]
    assert late > 0 and late == pytest.approx(earlier, rel=1e-3)   # a ramp: the output integrates the step


def test_papers_printed_model_is_refused_with_one_line():
    with pytest.raises(ModelFileError) as exc:
        load_model(PAPER)
    msg = str(exc.value)
    assert "not stable" in msg and "spectral radius 1" in msg and "\n" not in msg


def test_papers_printed_model_loads_when_explicitly_allowed_and_is_flagged():
    m = load_model(PAPER, allow_unstable=True)
    assert m.stable is False


def _write(tmp_path, d):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    return p


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d["wiener"].__setitem__("A", [[0.5, 0.1]]), "shapes do not agree"),
    (lambda d: d["wiener"].__setitem__("B", [1.0, 0.0, 0.0]), "shapes do not agree"),
    (lambda d: d["wiener"].__setitem__("C", [float("nan"), 0.0]), "non-finite"),
    (lambda d: d.__setitem__("version", 7), "version 7 is not supported"),
    (lambda d: d.__setitem__("fs_hz", -1), "fs_hz must be a positive number"),
    (lambda d: d["convolution"].__setitem__("kernel", []), "convolution.kernel is empty"),
    (lambda d: d["wiener"]["nonlinearity"].__setitem__("form", "magic"), "nonlinearity.form 'magic'"),
    (lambda d: d["wiener"]["nonlinearity"].__setitem__("cmu", [0.0, 0.0, 1.0] + [2.0] * 9), "strictly increasing"),
    (lambda d: d.__setitem__("input_stages", [{"name": "teleport", "params": {}}]), "unknown augmentation"),
    (lambda d: d["highpass"].__setitem__("sos", [[1.0, -2.0, 1.0, 1.0, -2.5, 1.0]]), "unstable"),
    (lambda d: d.pop("wiener"), "missing key 'wiener'"),
])
def test_bad_model_files_fail_with_one_line_naming_the_problem(tmp_path, rng, mutate, words):
    d = model_to_dict(make_model(rng))
    d["wiener"]["nonlinearity"] = {"form": "input_gain", "cmu": list(np.linspace(0, 0.02, 12)),
                                   "gain": [10.0] * 12}
    mutate(d)
    with pytest.raises(ModelFileError) as exc:
        load_model(_write(tmp_path, d))
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_not_json_and_missing_file_are_one_line_errors(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        load_model(p)
    with pytest.raises(ModelFileError, match="no such model file"):
        load_model(tmp_path / "missing.json")

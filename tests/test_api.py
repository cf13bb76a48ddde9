"""``rtlift.api``: the example of docs/API.md runs as printed, and the functions give what the
commands give (they are what the commands call)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from rtlift.app.cli import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "API.md"


@pytest.mark.slow
def test_the_documented_example_runs_and_matches_the_commands(tmp_path, monkeypatch, capsys):
    code = re.search(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, str(DOC), "exec"), {"__name__": "api_example"})
    out = capsys.readouterr().out
    work = tmp_path / "api-example"
    assert "accepted: ['periodic_disturbance']" in out
    assert (work / "figures" / "random.png").stat().st_size > 10_000
    report = json.loads((work / "diagnosis" / "report.json").read_text())
    after, before = (report[k]["records"]["random_pickup"]["rmse"] for k in ("augmented", "baseline"))
    assert after < before
    # the command, given the same (relative) paths, writes the very same model file, byte for byte
    assert main(["identify", "--static", "api-example/static.csv", "--single-burst", "api-example/single_burst.csv",
                 "--train", "api-example/sine_k0125.csv", "-o", str(tmp_path / "cli_model.json")]) == 0
    assert (tmp_path / "cli_model.json").read_bytes() == (work / "model.json").read_bytes()
    assert main(["validate", "--model", str(work / "model.json"), str(work / "random.csv"),
                 "--json", str(tmp_path / "v.json")]) == 0
    scored = json.loads((tmp_path / "v.json").read_text())["records"]["random"]
    printed = re.search(r"^random (\{.*\})$", out, re.M).group(1)
    assert scored["corr"] == pytest.approx(eval(printed)["corr"], abs=5e-5)   # printed rounded to 4 digits
    assert scored["corr"] > 0.9


def test_validate_takes_loaded_objects_and_refuses_the_other_kind_with_one_line(tmp_path):
    import numpy as np

    from rtlift.api import read_records, validate
    from rtlift.core.errors import UserError
    from rtlift.core.records import SisoRecord, write_siso_record
    from testkit.synthetic import make_model

    model = make_model(np.random.default_rng(3))
    write_siso_record(tmp_path / "g.csv", SisoRecord(np.arange(10) / 400.0, np.zeros(10), np.zeros(10),
                                                     {"fs_hz": "400"}, "g"))
    with pytest.raises(UserError, match="a generic \\(t,u,y\\) record, but the model is a lift model"):
        read_records([tmp_path / "g.csv"], model)
    from hil_sim.experiments import run_experiment

    rec = run_experiment("sine_k025", seed=4).to_record()
    rec = rec.slice(0, 4000)
    (result,) = validate(model, [rec])
    model.reset()
    want = model.simulate(rec.cmu, rec.cmu_envelope).total
    np.testing.assert_allclose(result.output.total, want, rtol=0, atol=1e-12)
    assert result.name == rec.name

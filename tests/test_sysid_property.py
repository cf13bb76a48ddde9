"""Never an internal error (issue 48): systems drawn by hypothesis — stable, integrating, marginal,
unstable, with dead time, static, noisy, with a constant or a saturated input, short — through
``rtlift identify --record``, ``validate`` and ``diagnose`` on files. Each command ends with exit 0
and a model and its scores, or with exit 1/2 and one line; never ``internal error``.

The fits run on small search options (orders 1–2, 6 knots, a few iterations: the code paths of
the defaults at a fraction of their cost)."""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path
from unittest import mock

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import signal

from rtlift.app.cli import main
from rtlift.core.records import SisoRecord, write_siso_record
from rtlift.diagnose import report
from rtlift.sysid import identify as sysid_identify
from rtlift.sysid.common import SisoOptions

FAST = replace(SisoOptions(), orders=(1, 2), knots=6, more_knots=(8,), more_knots_nfev=3, max_nfev=8, keep=1,
               feedback_orders=(1, 2), chain_starts=1)
SYSTEMS = ("stable", "integrating", "marginal", "unstable", "dead_time", "static", "noisy")
INPUTS = ("white", "steps", "constant", "saturated", "zero")


def _input(kind: str, n: int, rng: np.random.Generator, scale: float) -> np.ndarray:
    if kind == "white":
        return scale * rng.standard_normal(n)
    if kind == "steps":
        return scale * np.repeat(rng.standard_normal(n // 10 + 1), 10)[:n]
    if kind == "constant":
        return np.full(n, scale)
    if kind == "saturated":
        return np.clip(3 * scale * rng.standard_normal(n), -scale, scale)
    return np.zeros(n)


def _output(system: str, u: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    x = {"stable": lambda: signal.lfilter([0.3, 0.2], [1.0, -0.6], u),
         "integrating": lambda: np.cumsum(u),
         "marginal": lambda: signal.lfilter([0.1], [1.0, -2 * math.cos(0.3), 1.0], u),
         "unstable": lambda: signal.lfilter([0.1], [1.0, -1.08], u),
         "dead_time": lambda: np.concatenate([np.zeros(5), signal.lfilter([0.5], [1.0, -0.5], u)[:-5]]),
         "static": lambda: u,
         "noisy": lambda: 0.1 * u}[system]()
    y = np.tanh(x) + 0.2 * x**2
    spread = float(np.std(y)) or 1.0
    return y + noise * spread * rng.standard_normal(u.size) + (rng.standard_normal(u.size) if system == "noisy"
                                                                 else 0.0)


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "internal error" not in err, err
    return err


def _check(rc: int, err: str) -> None:
    assert rc in (0, 1, 2)
    if rc:
        lines = [ln for ln in err.strip().splitlines() if ln.startswith("rtlift: error:")]
        assert len(lines) == 1, err


DRAWS = dict(system=st.sampled_from(SYSTEMS), inp=st.sampled_from(INPUTS), n=st.integers(50, 150),
             noise=st.sampled_from([0.0, 0.05, 1.0]), scale=st.sampled_from([1e-3, 1.0, 1e3]),
             seed=st.integers(0, 2**31 - 1))
QUICK = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]


@settings(max_examples=200, deadline=None, suppress_health_check=QUICK)
@given(**DRAWS)
def test_identify_validate_diagnose_end_with_a_model_or_one_line(capsys, system, inp, n, noise, scale, seed):
    """200 draws; the diagnosis's figures are not drawn (their paths are written into the report
    as they would be): drawing them is 80 % of the time, and the next test draws them."""
    with mock.patch.object(report, "plot", lambda diag, out, fs: report._fig_paths(out)):
        _through_the_commands(capsys, system, inp, n, noise, scale, seed)


@settings(max_examples=15, deadline=None, suppress_health_check=QUICK)
@given(**DRAWS)
def test_the_diagnosis_draws_its_figures_for_any_system(capsys, system, inp, n, noise, scale, seed):
    _through_the_commands(capsys, system, inp, n, noise, scale, seed)


def _through_the_commands(capsys, system, inp, n, noise, scale, seed):
    rng = np.random.default_rng(seed)
    u = _input(inp, 2 * n, rng, scale)
    y = _output(system, u, rng, noise)
    with tempfile.TemporaryDirectory() as tmp, mock.patch.object(sysid_identify, "SisoOptions", lambda: FAST):
        d = Path(tmp)
        for name, part in (("est", slice(0, n)), ("val", slice(n, 2 * n))):
            write_siso_record(d / f"{name}.csv", SisoRecord(np.arange(n) / 10.0, u[part], y[part], {}, name))
        rc = main(["identify", "--record", str(d / "est.csv"), "-o", str(d / "m.json")])
        _check(rc, _one_line(capsys))
        if rc:
            return
        model = json.loads((d / "m.json").read_text())
        assert math.isfinite(model["metrics"]["holdout_rmse"]) and math.isfinite(model["metrics"]["train_rmse"])
        rc = main(["validate", "--model", str(d / "m.json"), str(d / "val.csv"), "--json", str(d / "v.json")])
        _check(rc, _one_line(capsys))
        if rc == 0:
            scores = json.loads((d / "v.json").read_text())["records"]["val"]
            assert scores["rmse"] >= 0 or math.isnan(scores["rmse"])
        rc = main(["diagnose", "--model", str(d / "m.json"), "--train", str(d / "est.csv"), "--validate",
                   str(d / "val.csv"), "--out", str(d / "diag")])
        _check(rc, _one_line(capsys))
        if rc == 0:
            report = json.loads((d / "diag" / "report.json").read_text())
            assert set(report["augmented"]["records"]) == {"est", "val"}

"""The model's error as the loop sees it (``benchmarks/control_family.py --excess``): the tables
:class:`rtlift.app.control_design.SensitivityError` is made of, from measured draws."""

from __future__ import annotations

import json
import math

import numpy as np

from benchmarks.control_family import excess, load_s_error
from rtlift.app.control_design import BAND_CLASS_DB, SensitivityError


def _row(f: float, measured_db: float, predicted_db: float) -> dict:
    return {"f_hz": f, "suppression_db": measured_db, "predicted_s_db": predicted_db}


def _abs(db: float) -> float:
    return 10.0 ** (db / 20.0)


def test_the_excess_is_the_largest_over_draws_kept_apart_by_the_bound_it_stood_near(tmp_path):
    """In the band (prediction ≤ BAND_CLASS_DB) and elsewhere apart; each the largest absolute excess
    over the draws (a shortfall counts as 0); a frequency with no prediction of a class takes the
    nearest one's value; the JSON loads as the design's :class:`SensitivityError`."""
    rows = [{"draw": 4, "rows": [_row(0.2, -6.0, -6.4), _row(0.5, +0.5, -2.0), _row(1.0, 2.0, 2.2)]},
            {"draw": 5, "rows": [_row(0.2, -6.1, -6.9), _row(0.5, -6.0, -6.2), _row(1.0, 2.5, 2.0)]}]
    assert BAND_CLASS_DB < -2.0
    out = excess(rows)
    assert out["f_hz"] == [0.2, 0.5, 1.0] and out["draws"] == [4, 5]
    band_02 = max(_abs(-6.0) - _abs(-6.4), _abs(-6.1) - _abs(-6.9))
    assert out["band"][0] == round(band_02, 4) and out["band_draw"][0] == 5
    assert out["band"][1] == round(_abs(-6.0) - _abs(-6.2), 4) and out["band_draw"][1] == 5
    assert out["band_draw"][2] is None and out["band"][2] == out["band"][1]      # none stood in the band at 1 Hz
    assert out["peak"][1] == round(_abs(0.5) - _abs(-2.0), 4) and out["peak_draw"][1] == 4
    assert out["peak"][2] == round(_abs(2.5) - _abs(2.0), 4) and out["peak_draw"][2] == 5   # draw 4's 0 lost
    assert out["peak_draw"][0] is None and out["peak"][0] == out["peak"][1]
    path = tmp_path / "excess.json"
    path.write_text(json.dumps(out), encoding="utf-8")
    err = load_s_error(str(path))
    assert isinstance(err, SensitivityError)
    assert math.isclose(float(err.at(np.array([0.35]), "band")[0]), 0.5 * (out["band"][0] + out["band"][1]),
                        rel_tol=1e-9)
    assert float(err.at(np.array([3.0]), "peak")[0]) == out["peak"][2]

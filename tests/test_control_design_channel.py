"""The internal-model programme's channel bound (:class:`rtlift.app.control_design.YoulaProgram`'s
``channel_bound``): each channel's own part of T, |Q_A P_A| and |Q_X P_X|, bounded by B = 1 + M.

Without it the programme may meet every bound on T = Q_A P_A + Q_X P_X with parts that are large and
opposed: they cancel in T but not on the sensor's noise, which reaches the two channels differently
(docs/results/control.md, "Eighth pass")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtlift.app.control_design import NYQUIST_GAIN_MAX, YoulaProgram, load_design, plant_response

MODEL = Path(__file__).parent / "data" / "bench_model.json"


def test_the_channel_bound_holds_each_channel_s_part_of_t_and_keeps_the_band():
    """On the bench model's cached design (its second scheduled point, the programme alone at 0.3 Hz):
    unbounded, the parts reach > 100 (|T| itself ≤ 1 + M); bounded by B = 1 + M, each part stays
    ≤ λ B on a grid 10× denser than the programme's (1 % for the polygon between its points), with
    |S_o| ≤ 0.5 λ on the band, T(1) = 1 and Q_X(1) = 0 as before."""
    cached = load_design(str(next(MODEL.parent.glob("bench_model.design-*.json"))))
    pt = cached.scheduled[1]
    g0 = float(np.sum(pt.plant))
    p, q = np.asarray(pt.plant) / g0, np.asarray(pt.plant_point) / g0
    bound = 1.0 + 10.0 ** (cached.targets.peak_db / 20.0)
    f = np.geomspace(0.01, 0.5 / cached.dt, 2000)
    z = np.exp(2j * np.pi * f * cached.dt)
    parts = {}
    for b in (None, bound):
        prog = YoulaProgram(p, q, cached.dt, cached.targets.peak_db, f_o=pt.observer_response,
                            unc=cached.uncertainty, gm_db=cached.targets.gm_db, nyquist_gain=NYQUIST_GAIN_MAX * g0,
                            controller=True, channel_bound=b)
        qa, qx, lam = prog.solve(0.3)
        ta = plant_response(p, z) * np.polyval(qa[::-1], 1 / z)
        tx = plant_response(q, z) * np.polyval(qx[::-1], 1 / z)
        parts[b] = (np.abs(ta).max(), np.abs(tx).max(), lam)
        assert np.abs(ta + tx).max() <= 1.0 + 10.0 ** (cached.targets.peak_db / 20.0) + 1e-6
        top = prog.top(0.3)
        s_o = np.abs(1.0 - prog.gust[:top + 1] @ np.r_[qa, qx])
        assert s_o.max() <= 0.5 * lam + 1e-6
        assert float(np.sum(p) * np.sum(qa) + np.sum(q) * np.sum(qx)) == pytest.approx(1.0, abs=1e-7)
        assert float(np.sum(qx)) == pytest.approx(0.0, abs=1e-7)
    assert min(parts[None][:2]) > 100.0
    a, x, lam = parts[bound]
    assert lam <= 1.0
    assert max(a, x) <= 1.01 * lam * bound

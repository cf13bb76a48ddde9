"""The internal-model programme's channel bound (:class:`rtlift.app.control_design.YoulaProgram`'s
``channel_bound``): each channel's own part of T, |Q_A P_A| and |Q_X P_X|, bounded by B = 1 + M.

Without it the programme may meet every bound on T = Q_A P_A + Q_X P_X with parts that are large and
opposed: they cancel in T but not on the sensor's noise, which reaches the two channels differently
(docs/results/control.md, "Eighth pass")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtlift.app.control_design import NYQUIST_GAIN_MAX, ModelError, YoulaProgram, load_design, plant_response

MODEL = Path(__file__).parent / "data" / "bench_model.json"


def test_the_channel_bound_and_the_robust_rows_hold_and_keep_the_band():
    """On the bench model's cached design (its second scheduled point, the programme alone at 0.3 Hz):
    unbounded, the parts reach > 100 (|T| itself ≤ 1 + M); bounded by B = 1 + M, each part stays
    ≤ λ B on a grid 10× denser than the programme's (1 % between its points, where it is exact), with
    |S_o| ≤ 0.5 λ on the band, T(1) = 1 and Q_X(1) = 0 as before. The bounded programme also carries a
    :class:`ModelError` (a made-up envelope, 3 % to 1 Hz rising to 60 % / 30 % at 2 Hz: the rows'
    arithmetic is what is tested): where its rows are (from 0.5 Hz) |S| and |S_o| plus
    M(δ_A|T_A| + δ_X|T_X|) stay ≤ λM, so |S|/|1 + D| and |S_o|/|1 + D| do for errors of the bound's
    size in any phase, and the band's bound is deepened by m = −20 log₁₀(1 − 0.03) = 0.26 dB."""
    err = ModelError((0.0, 1.0, 2.0, 4.0), (0.03, 0.03, 0.6, 0.6), (0.03, 0.03, 0.3, 0.3), "test")
    assert err.band_margin_db() == pytest.approx(0.265, abs=1e-3)
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
                            controller=True, channel_bound=b, model_error=None if b is None else err)
        qa, qx, lam = prog.solve(0.3)
        depth = 1.0 if b is None else 10.0 ** (-err.band_margin_db() / 20.0)
        ta = plant_response(p, z) * np.polyval(qa[::-1], 1 / z)
        tx = plant_response(q, z) * np.polyval(qx[::-1], 1 / z)
        parts[b] = (np.abs(ta).max(), np.abs(tx).max(), lam)
        assert np.abs(ta + tx).max() <= 1.0 + 10.0 ** (cached.targets.peak_db / 20.0) + 1e-6
        top = prog.top(0.3)
        s_o = np.abs(1.0 - prog.gust[:top + 1] @ np.r_[qa, qx])
        assert s_o.max() <= 0.5 * lam * depth + 1e-6
        assert float(np.sum(p) * np.sum(qa) + np.sum(q) * np.sum(qx)) == pytest.approx(1.0, abs=1e-7)
        assert float(np.sum(qx)) == pytest.approx(0.0, abs=1e-7)
    assert min(parts[None][:2]) > 100.0
    a, x, lam = parts[bound]
    assert lam <= 1.0
    assert max(a, x) <= 1.01 * lam * bound
    m = 10.0 ** (cached.targets.peak_db / 20.0)
    fr = prog.f_robust
    zr = np.exp(2j * np.pi * fr * cached.dt)
    ta, tx = plant_response(p, zr) * np.polyval(qa[::-1], 1 / zr), plant_response(q, zr) * np.polyval(qx[::-1], 1 / zr)
    da, dx = err.deltas(fr)
    d = da * np.abs(ta) + dx * np.abs(tx)
    assert prog.n_aux == 2 * fr.size > 0 and fr.min() >= 0.5
    assert (m * d).max() > 0.1           # the error is not negligible where the rows are
    s_o_rob = 1.0 - prog.gust_robust @ np.r_[qa, qx]
    for s_x in (1.0 - ta - tx, s_o_rob):
        assert np.all(np.abs(s_x) + m * d <= lam * m + 1e-6)
        for phase in np.exp(2j * np.pi * np.arange(8) / 8):    # errors of the bound's size, any phase
            assert np.abs(s_x / (1.0 + phase * d)).max() <= lam * m + 1e-6


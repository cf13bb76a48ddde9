"""The ``pi2j`` structure's joint search (rtlift.app.control_design.design_joint, schedule_mix).

On the bench model's cached design (tests/data: its scheduled points and the half-way points between
them, each with its lifted plant, observer and pulse response): the half-way gains the search scores are
the ones :class:`~rtlift.app.control.LiftController` runs there, and the joint search, started from the
cached schedule, removes the half-way shortfall that schedule leaves on the search's grid without
narrowing the smallest band; the gains it returns meet every target at every point on the dense check."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtlift.app.control import ControlConfig, LiftController
from rtlift.app.control_design import (
    Design,
    Gains,
    analysis_grid,
    check_point,
    design_joint,
    gust_gain,
    load_design,
    observer_response,
    point_cost,
    schedule_mix,
)
from rtlift.model.modelfile import load_model

MODEL = Path(__file__).parent / "data" / "bench_model.json"


@pytest.fixture(scope="module")
def cached() -> Design:
    return load_design(str(next(MODEL.parent.glob("bench_model.design-*.json"))))


def test_schedule_mix_is_the_controller_s_interpolation():
    """Half-way and a quarter of the way: every gain as the controller sets it (T_i linear), to 1e-12."""
    model = load_model(MODEL)
    lo, hi = Gains(1.0, 0.05, 0.1, 0.5, 0.2, 0.3, 0.6), Gains(3.0, 0.01, 0.3, 0.7, 1.0, -0.2, 0.1)
    rows = tuple((cmu, g.kp, 0.02 / g.ki, g.a, g.b, g.kx, g.c, g.d) for cmu, g in ((0.002, lo), (0.012, hi)))
    ctl = LiftController(model, ControlConfig(fs_hz=400.0, period=8, schedule=rows))
    for w in (0.5, 0.25):
        ctl._schedule_at(0.002 + w * 0.01)
        g = schedule_mix(lo, hi, w)
        run = (ctl.kp, ctl._gain_i, ctl._a, ctl._b, ctl.kx, ctl._c, ctl._d)
        np.testing.assert_allclose((g.kp, g.ki, g.a, g.b, g.kx, g.c, g.d), run, rtol=1e-12, atol=1e-15)


def test_the_joint_search_clears_the_half_way_shortfall_without_narrowing_the_band(cached):
    """Start: the cached schedule, whose half-way points fall short on the search's grid (the search's
    0.15 dB |S| margin; total shortfall > 0.5). After 600 evaluations: no shortfall at any of the 7
    points, the smallest f₆ within 0.01 Hz of the start's, and every target met on the dense check."""
    pts, dt = cached.points, cached.dt
    assert [p.designed for p in pts] == [True, False] * (len(cached.scheduled) - 1) + [True]
    f = analysis_grid(dt, 800)
    measures = [point_cost(np.asarray(p.plant), np.asarray(p.plant_point), dt, cached.targets, f,
                           observer_response(p.observer, p.fs_hz, f, p.observer_tail, p.observer_period),
                           cached.uncertainty.weight(f), gust_gain(p.pulse, p.fs_hz, cached.period, f))
                for p in pts]

    def scored(gs: list[Gains]) -> list[tuple[float, float]]:
        every = [gs[0]]
        for a, b in zip(gs, gs[1:], strict=False):
            every += [schedule_mix(a, b, 0.5), b]
        return [m(g) for m, g in zip(measures, every, strict=True)]

    start = [p.gains for p in cached.scheduled]
    before = scored(start)
    assert sum(s for _, s in before) > 0.5
    out = design_joint(start, measures, max_evals=600)
    after = scored(out)
    assert max(s for _, s in after) == 0.0
    assert min(b for b, _ in after) > min(b for b, _ in before) - 0.01
    every = [out[0]]
    for a, b in zip(out, out[1:], strict=False):
        every += [schedule_mix(a, b, 0.5), b]
    checked = [check_point(p.cmu, p.dcl, np.asarray(p.plant), np.asarray(p.plant_point), g, dt, np.asarray(p.observer),
                           p.fs_hz, cached.uncertainty, designed=p.designed, tail=p.observer_tail,
                           period=p.observer_period, cross_check=False, pulse=p.pulse)
                 for p, g in zip(pts, every, strict=True)]
    design = Design(checked, dt, cached.period, cached.margin, cached.targets, cached.uncertainty)
    assert design.violations() == []
    assert design.summary()["f6_hz_min"] == pytest.approx(min(b for b, _ in after), abs=0.01)


def test_an_unknown_joint_objective_is_refused(cached):
    with pytest.raises(ValueError, match="objective"):
        design_joint([p.gains for p in cached.scheduled], [], objective="max")

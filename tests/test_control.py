"""rtlift.app.control on the model: the closed loop in simulation with the hybrid model as the
plant (bursts every 50 samples, the envelope applied at the next onset, measurement noise
σ 0.004, an actuator fade the controller is not told about) and the observer in the loop;
references parsed from the command line's specs.

The model is tests/data/bench_model.json: identified on the simulated bench (seed 1) and
tuned for the observer exactly as ``tests.test_observer_bench.bench_model(("random",))``,
stored so these tests do not spend a minute identifying it."""

from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from rtlift.app.control import ACTUATOR_CMU_LIMIT, ControlConfig, LiftController, static_map
from rtlift.app.reference import parse_reference
from rtlift.core.errors import UserError
from rtlift.core.rate import FS_HZ
from rtlift.model.modelfile import load_model
from rtlift.observer import Observer

MODEL = Path(__file__).parent / "data" / "bench_model.json"
FS = int(FS_HZ)
PERIOD = 50
BURST = 4
TOL_SETTLE = 0.01


def closed_loop(reference, *, feedback=True, seconds=24.0, fade=(0.75, 0.4), seed=0):
    """Truth ΔCL, estimate and applied envelope of a closed-loop run on the model."""
    model = load_model(MODEL)
    plant = load_model(MODEL)
    observer = Observer.from_model(model)
    ctl = LiftController(model, ControlConfig(feedback=feedback))
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    r = reference(t)
    y, est, env = np.zeros(n), np.zeros(n), np.zeros(n)
    applied = decided = on_time = 0.0
    for k in range(n):
        if k % PERIOD == 0:
            applied = decided
        cmu = applied if k % PERIOD < BURST else 0.0
        f = 1.0 if fade is None else fade[0] + (1 - fade[0]) * math.exp(-on_time / fade[1])
        on_time += (cmu > 0) / FS
        y[k] = plant.step(cmu * f, applied * f)[0]
        e = observer.step(cmu, applied, y[k] + 0.004 * rng.standard_normal())
        est[k] = e.dcl
        decided = ctl.step(e, float(r[k]))
        env[k] = applied
    return {"t": t, "r": r, "y": y, "est": est, "env": env, "ctl": ctl}


def tracking_rmse(run, start_s=2.0):
    sos = signal.butter(2, 1.0, fs=FS, output="sos")
    k = int(start_s * FS)
    return float(np.sqrt(np.mean((signal.sosfiltfilt(sos, run["y"])[k:]
                                  - signal.sosfiltfilt(sos, run["r"])[k:]) ** 2)))


def settling_s(run, t0, seconds=4.0):
    """Time after ``t0`` until the burst-period mean of the truth stays within 0.01 of r."""
    k0 = int(t0 * FS)
    mean = np.convolve(run["y"], np.ones(PERIOD) / PERIOD, mode="same")
    err = np.abs(mean[k0:k0 + int(seconds * FS)] - run["r"][k0 + 10])
    bad = np.nonzero(err > TOL_SETTLE)[0]
    return (bad[-1] + 1) / FS if len(bad) else 0.0


def steps(t):
    return np.where(t < 2, 0.0, np.where(t < 8, 0.10, np.where(t < 14, 0.16, 0.06)))


def test_the_inverse_static_map_is_the_models_static_map_inverted():
    model = load_model(MODEL)
    ctl = LiftController(model)
    cmu, dcl = static_map(model, 0.022)
    for c in (0.002, 0.008, 0.015, 0.021):
        assert ctl.inverse(float(np.interp(c, cmu, dcl))) == pytest.approx(c, rel=1e-6)
    assert ctl.inverse(-1.0) == 0.0 and ctl.inverse(10.0) == pytest.approx(ACTUATOR_CMU_LIMIT)
    assert 0.18 < ctl.dcl_max < 0.26 and ctl.dcl_max == pytest.approx(float(dcl[-1]), rel=1e-12)
    # the feedback's reach: the map extrapolated to the actuator's 200 V, the same below 0.022
    assert ACTUATOR_CMU_LIMIT == pytest.approx(0.02444, rel=1e-3)
    assert ctl.dcl_reach > ctl.dcl_max + 0.005
    reach_cmu, reach_dcl = static_map(model, 0.022, reach=ACTUATOR_CMU_LIMIT)
    assert np.array_equal(reach_dcl[:dcl.size], dcl) and reach_cmu[-1] == ACTUATOR_CMU_LIMIT
    assert np.max(np.diff(reach_cmu)) <= 0.022 / 200 * (1 + 1e-9)
    # with the feedback off, the feedforward stays on the identified map
    ff = LiftController(model, ControlConfig(feedback=False))
    assert ff.inverse(10.0) == pytest.approx(0.022) and ff.dcl_reach == ff.dcl_max == ctl.dcl_max


def test_feedback_halves_the_tracking_error_of_feedforward_under_an_actuator_fade():
    ff = tracking_rmse(closed_loop(steps, feedback=False))
    fb = tracking_rmse(closed_loop(steps, feedback=True))
    assert fb <= 0.5 * ff and fb <= 0.015


def test_a_step_settles_within_one_and_a_half_seconds():
    run = closed_loop(lambda t: np.where(t < 2, 0.0, np.where(t < 9, 0.08, 0.15)), seconds=14.0)
    assert settling_s(run, 9.0) <= 1.5


def test_no_windup_after_a_reference_beyond_reach():
    run = closed_loop(lambda t: np.where(t < 2, 0.0, np.where(t < 6, 0.10, np.where(t < 10, 0.35, 0.10))),
                      seconds=16.0, fade=None)
    ctl = run["ctl"]
    reached = run["env"][int(9.5 * FS)]
    assert reached == pytest.approx(ctl.config.cmu_reach) and ctl.config.cmu_reach == ACTUATOR_CMU_LIMIT
    assert settling_s(run, 10.0) <= 1.0


def test_the_envelope_stays_within_the_actuator_limits_and_changes_only_once_per_period():
    run = closed_loop(lambda t: 0.3 * np.sin(2 * np.pi * 0.5 * t), seconds=6.0)
    env = run["env"]
    assert env.min() >= 0.0 and env.max() == pytest.approx(ACTUATOR_CMU_LIMIT)
    changes = np.nonzero(np.diff(env))[0] + 1
    assert np.all(changes % PERIOD == 0)


@pytest.mark.parametrize("feedback", [False, True])
def test_the_first_onset_of_tracking_carries_the_first_decision(feedback):
    """The live loop (:class:`rtlift.app.closed_loop.ControlLoop`, in process on the bench) decides
    at its first tracked sample: the actuator fires from the first burst onset after tracking
    starts, at most one period in (it waited for a period's average first and fired only from the
    second onset, 100 samples in)."""
    from rtlift.app.hil_tracking import InProcessTracking

    model = load_model(MODEL)
    run = InProcessTracking(model, LiftController(model, ControlConfig(feedback=feedback)), "steps:0.06@0", 1.0,
                            effects=()).run()
    _, _, env = run.traces()
    assert 0 < np.flatnonzero(env > 0)[0] <= PERIOD


def test_step_allocates_nothing():
    ctl = LiftController(load_model(MODEL))
    for _ in range(200):
        ctl.step(0.05, 0.1)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for k in range(5000):
        ctl.step(0.05 + 1e-5 * k, 0.1)
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename")
                if s.traceback[0].filename.endswith("control.py"))
    assert grown <= 256  # a few float attributes replaced, nothing per step


@pytest.mark.parametrize("spec,t,value", [
    ("steps:0.1@2,0.15@8", 1.0, 0.0), ("steps:0.1@2,0.15@8", 5.0, 0.1),
    ("steps:0.1@2,0.15@8", 9.0, 0.15), ("sine:mean=0.1,amp=0.05,hz=0.25", 1.0, 0.15),
])
def test_references_from_the_command_line(spec, t, value):
    assert parse_reference(spec).at(t) == pytest.approx(value)


def test_a_reference_file_is_interpolated(tmp_path):
    f = tmp_path / "ref.csv"
    f.write_text("t,dcl_ref\n0,0\n2,0.1\n4,0.1\n")
    ref = parse_reference(str(f))
    assert (ref.at(1.0), ref.at(3.0), ref.at(10.0)) == pytest.approx((0.05, 0.1, 0.1))


@pytest.mark.parametrize("spec", ["steps:", "steps:0.1@x", "steps:0.1@3,0.2@1", "sine:mean=0.1,amp=0.1",
                                  "sine:mean=0.1,amp=0.1,hz=0", "ramp:1", "nofile.csv"])
def test_a_bad_reference_is_one_line(spec):
    with pytest.raises(UserError) as exc:
        parse_reference(spec)
    assert "\n" not in str(exc.value)


def test_the_static_map_of_an_interaction_model_with_the_static_lift_is_its_steady_lift():
    """Issue 31: with the static lift as the interaction structure's Wiener input, the controller's
    map takes the Wiener part's input from the ``delivered_envelope`` stage (f(Cμ_env)/s, not
    Cμ_env) and S at it: at every level the map equals the model's own mean lift once a held
    envelope has settled under lift-optimal bursting (G_H, G and S flat, so that m's ripple within
    a period has no mean effect)."""
    from rtlift.blocks.delivered import DeliveredEnvelope
    from rtlift.model.modelfile import model_from_dict, model_to_dict
    from testkit.synthetic import interaction_model

    m = interaction_model(np.random.default_rng(11), 40, 1)
    d = model_to_dict(m)
    conv = d["convolution"]["interaction"]
    conv["gains"] = [0.4] * len(conv["knots"])
    conv["gains_h"] = [0.9] * len(conv["knots"])
    conv["gains_static"] = [1.5] * len(conv["knots"])
    st = m.input_stages[-1]
    conv["momentum"]["duty"] = st.burst_samples / st.period_samples     # d: the lift-optimal duty, as identified
    m = model_from_dict(d)
    grid = np.linspace(0, 0.022, 8)
    m.input_stages = (DeliveredEnvelope(st.time_constant_s, st.burst_samples, st.period_samples, FS_HZ,
                                        (grid, np.linspace(14.0, 8.0, 8)), 2.0),)
    m.__post_init__()
    cmu_grid, smap = static_map(m, 0.022, 12)
    n = int(60 * FS_HZ)
    on = (np.arange(n) % st.period_samples) < st.burst_samples
    rising = np.flatnonzero(np.diff(smap) > 0) + 1          # not levelled by the map's monotone envelope
    assert rising.size >= 6
    for c, want in zip(cmu_grid[rising], smap[rising], strict=True):
        m.reset()
        lift = m.simulate(np.where(on, c, 0.0), np.full(n, c)).total
        got = lift[-st.period_samples * (int(5 * FS_HZ) // st.period_samples):].mean()
        assert abs(got - want) <= 1e-3 * abs(want) + 1e-6, (c, got, want)

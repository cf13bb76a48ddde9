"""The observer on the simulated bench (σ(ΔCL) ≈ 0.004): accuracy against the bench's
noise-free ΔCL, a zero drift, and NIS consistency. The model is identified from the
standard campaign (seed 1, the paper's 2nd-order Wiener LTI) and the observer's Q and R
are tuned on seed-1 records; every score is on seed-2 records it has not seen."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from hil_sim.experiments import run_experiment
from rtlift.hybrid import HybridModel
from rtlift.identify.campaign import IdentifyOptions, identify_hybrid
from rtlift.modelfile import model_from_dict, model_to_dict
from rtlift.observer import Observer, tune_observer
from rtlift.records import Record

TARE = 800                                          # the bench's 2 s actuator-off start
TRAINS = ("train_T1p75", "train_T3p5", "train_T7")


@functools.cache
def _identified() -> dict:
    recs = {n: run_experiment(n, seed=1).to_record() for n in ("static", "single_burst", "sine_k0125")}
    idf = identify_hybrid(recs["static"], recs["single_burst"], recs["sine_k0125"], IdentifyOptions(order=2))
    return model_to_dict(idf.model)


@functools.cache
def _tuned(experiments: tuple[str, ...]) -> dict:
    model = model_from_dict(_identified())
    return tune_observer(model, [run_experiment(n, seed=1).to_record() for n in experiments])


def bench_model(tuned_on: tuple[str, ...] = ("random",)) -> HybridModel:
    """The identified model with observer settings tuned on seed-1 records (a fresh copy)."""
    model = model_from_dict(_identified())
    model.observer_config = dict(_tuned(tuned_on))
    return model


def observe(model: HybridModel, rec: Record) -> dict[str, np.ndarray]:
    obs = Observer.from_model(model)
    out = obs.run(rec.cmu, rec.cmu_envelope, rec.dcl)
    out["observer"] = obs
    return out


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a[TARE:] - b[TARE:]) ** 2)))


def test_on_burst_trains_the_estimate_beats_the_raw_measurement_and_the_open_loop_model():
    model = bench_model(TRAINS)
    est, raw, ol, truth = [], [], [], []
    for name in TRAINS:
        rec = run_experiment(name, seed=2).to_record()
        out = observe(model, rec)
        assert rmse(out["dcl"], rec.extra["dcl_true"]) < rmse(rec.dcl, rec.extra["dcl_true"]), name
        est.append(out["dcl"][TARE:])
        raw.append(rec.dcl[TARE:])
        ol.append(out["model_dcl"][TARE:])
        truth.append(rec.extra["dcl_true"][TARE:])
    est, raw, ol, truth = map(np.concatenate, (est, raw, ol, truth))
    e_obs, e_raw, e_ol = (float(np.sqrt(np.mean((x - truth) ** 2))) for x in (est, raw, ol))
    assert 0.0035 < e_raw < 0.0045                   # the bench's sensor noise
    assert e_obs <= 0.75 * e_raw
    assert e_obs <= 0.50 * e_ol


def test_with_a_zero_drift_the_estimate_stays_unbiased_while_the_open_loop_model_drifts_away():
    rate = 1.5e-3                                    # ΔCL per second, the top of the effect's range
    model = bench_model(TRAINS)
    rec = run_experiment("train_T1p75", seed=2, effects=[f"zero_drift:rate_per_s={rate}"]).to_record()
    drift = rate * rec.t
    drift -= drift[:TARE][rec.cmu[:TARE] == 0].mean()   # the tare removes its start
    seen = rec.extra["dcl_true"] + drift             # what a noise-free balance would read
    out = observe(model, rec)
    last = slice(-800, None)
    assert drift[-1] > 0.01
    assert abs(np.mean(out["dcl"][last] - seen[last])) < 0.0015
    assert np.mean(seen[last] - out["model_dcl"][last]) > 0.6 * drift[-1]


def test_nis_stays_in_its_95_percent_band_on_the_default_bench():
    model = bench_model(("random",))
    assert model.observer_config["R"] == pytest.approx(0.004**2, rel=0.3)   # from the tare seconds
    rec = run_experiment("random", seed=2).to_record()
    obs = observe(model, rec)["observer"]
    assert 0.90 <= obs.nis_band_fraction <= 0.99
    assert 0.7 <= obs.nis_mean <= 1.4
    assert obs.rejected < 0.02 * obs.updates


def test_the_tuned_settings_round_trip_through_the_model_file(tmp_path):
    from rtlift.modelfile import load_model, save_model

    model = bench_model(("random",))
    save_model(model, tmp_path / "m.json", observer=model.observer_config)
    back = Observer.from_model(load_model(tmp_path / "m.json"))
    assert back.config.to_dict() == Observer.from_model(model).config.to_dict()
    assert 0.6 <= back.config.extra["nis_mean"] <= 1.5

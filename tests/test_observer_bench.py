"""The observer on the simulated bench (σ(ΔCL) ≈ 0.004): accuracy against the bench's
noise-free ΔCL, a zero drift, and NIS consistency.

The model is identified by the default ``identify_hybrid`` (automatic Wiener order) from the
clean standard campaign of seed 1, and the observer's noise settings are tuned by
``tune_observer`` on seed-1 records (sine_k0125, random, train_T1p75). Every score is on
seed-2 records neither has seen."""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hil_sim.experiments import run_experiment
from rtlift.core.records import Record
from rtlift.identify.campaign import identify_hybrid
from rtlift.model.hybrid import HybridModel
from rtlift.model.modelfile import model_from_dict, model_to_dict
from rtlift.observer import Observer, tune_observer
from testkit.shared import shared_dir

TARE = 800                                          # the bench's 2 s actuator-off start
TRAINS = ("train_T1p75", "train_T3p5", "train_T7")
TUNED_ON = ("sine_k0125", "random", "train_T1p75")


def _shared_json(name: str, key: tuple, compute: Callable[[], dict]) -> dict:
    """``compute()`` once per test run, by whichever process asks first, read back by the others
    (the modules that need it run in several xdist workers: :func:`testkit.shared.shared_dir`);
    the JSON round trip of these dicts is exact."""
    def build(out: Path) -> None:
        (out / "result.json").write_text(json.dumps(compute()))

    return json.loads((shared_dir(name, key, build) / "result.json").read_text())


@functools.cache
def _identified() -> dict:
    """The paper's hybrid identified on the seed-1 campaign, as its model-file dict."""
    def compute() -> dict:
        recs = {n: run_experiment(n, seed=1).to_record() for n in ("static", "single_burst", "sine_k0125")}
        return model_to_dict(identify_hybrid(recs["static"], recs["single_burst"], recs["sine_k0125"]).model)

    return _shared_json("bench-identified", (1,), compute)


@functools.cache
def _tuned(experiments: tuple[str, ...]) -> dict:
    """The observer settings tuned for :func:`_identified` on the seed-1 records ``experiments``."""
    def compute() -> dict:
        model = model_from_dict(_identified())
        return tune_observer(model, [run_experiment(n, seed=1).to_record() for n in experiments])

    return _shared_json("bench-tuned", (1, experiments), compute)


@functools.cache
def _test_record(name: str) -> Record:
    return run_experiment(name, seed=2).to_record()


def bench_model(tuned_on: tuple[str, ...] = TUNED_ON) -> HybridModel:
    """The identified model with the observer settings tuned on seed-1 records (a fresh copy)."""
    model = model_from_dict(_identified())
    model.observer_config = dict(_tuned(tuned_on))
    return model


def observe(model: HybridModel, rec: Record) -> dict[str, np.ndarray]:
    obs = Observer.from_model(model)
    out = obs.run(rec.cmu, rec.cmu_envelope, rec.dcl)
    out["observer"] = obs
    return out


def errors(names: tuple[str, ...]) -> dict[str, float]:
    """RMSE against the noise-free ΔCL after the tare, pooled over ``names``: observer, raw
    measurement, open-loop model."""
    model = bench_model()
    est, raw, ol, truth = [], [], [], []
    for name in names:
        rec = _test_record(name)
        out = observe(model, rec)
        est.append(out["dcl"][TARE:])
        raw.append(rec.dcl[TARE:])
        ol.append(out["model_dcl"][TARE:])
        truth.append(rec.extra["dcl_true"][TARE:])
    est, raw, ol, truth = map(np.concatenate, (est, raw, ol, truth))
    return {k: float(np.sqrt(np.mean((x - truth) ** 2))) for k, x in (("obs", est), ("raw", raw), ("ol", ol))}


@pytest.mark.parametrize("name", ["sine_k0125", "random"])
def test_on_high_amplitude_records_the_estimate_beats_raw_by_25_and_open_loop_by_50_percent(name):
    """Issue 6's criterion, per record, where the burst ripple's model error is largest."""
    e = errors((name,))
    assert 0.0033 < e["raw"] < 0.0040                # the bench's sensor noise
    assert e["obs"] <= 0.75 * e["raw"]
    assert e["obs"] <= 0.50 * e["ol"]


def test_on_burst_trains_the_estimate_beats_raw_by_25_percent_each_and_open_loop_by_50_pooled():
    """Per train the raw criterion; the open-loop one pooled over the three trains (at
    T = 1.75 t⁺ alone the open-loop model is already within noise level: 0.0027)."""
    for name in TRAINS:
        e = errors((name,))
        assert e["obs"] <= 0.75 * e["raw"], name
    pooled = errors(TRAINS)
    assert 0.0033 < pooled["raw"] < 0.0042
    assert pooled["obs"] <= 0.50 * pooled["ol"]


def test_with_a_zero_drift_the_estimate_stays_unbiased_while_the_open_loop_model_drifts_away():
    rate = 1.5e-3                                    # ΔCL per second, the top of the effect's range
    model = bench_model()
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
    model = bench_model()
    cfg = model.observer_config
    total = cfg["R"] + cfg["q_noise"] * _ar2_variance(cfg["noise_ar"])
    assert cfg["measurement_noise_std"] == pytest.approx(0.004, rel=0.15)   # from the tare seconds
    assert total == pytest.approx(cfg["measurement_noise_std"] ** 2, rel=0.1)  # white + buffeting
    assert len(cfg["noise_ar"]) == 2
    nll = cfg["harmonics_nll"]                        # the ripple harmonics chosen by likelihood
    assert set(nll) == {"8", "12"} and nll[str(cfg["ripple_harmonics"])] == min(nll.values()) == cfg["nll"]
    for name in ("random", "sine_k0125"):
        obs = observe(model, _test_record(name))["observer"]
        assert 0.92 <= obs.nis_band_fraction <= 0.97, name
        assert 0.85 <= obs.nis_mean <= 1.2, name
        assert obs.rejected < 0.005 * obs.updates, name


def _ar2_variance(a: list[float]) -> float:
    a1, a2 = a
    return (1 - a2) / ((1 + a2) * ((1 - a2) ** 2 - a1**2))


def test_the_tuned_settings_round_trip_through_the_model_file(tmp_path):
    from rtlift.model.modelfile import load_model, save_model

    model = bench_model()
    save_model(model, tmp_path / "m.json", observer=model.observer_config)
    back = Observer.from_model(load_model(tmp_path / "m.json"))
    assert back.config.to_dict() == Observer.from_model(model).config.to_dict()
    assert 0.8 <= back.config.extra["nis_mean"] <= 1.25

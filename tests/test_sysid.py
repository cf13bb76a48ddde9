"""Generic single-input records and models (the measured benchmarks, a user's own rig).

The model u → G₁ → f → G₂ → y streams and batches alike; its file round-trips; a record of the
other kind is refused with one line; and on the measured WH2009 circuit (vendored in
``rtlift/data/benchmarks/``) the residual of a Wiener model leads to the output block it lacks.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rtlift.app.cli import main
from rtlift.blocks.highpass import HighPassFilter
from rtlift.blocks.wiener import OutputNonlinearity
from rtlift.core.errors import RecordError
from rtlift.core.records import SisoRecord, read_siso_record, write_siso_record
from rtlift.model.siso import FeedbackModel, SaturatedModel, SisoModel, StoreChainModel
from rtlift.model.siso_file import model_from_dict
from rtlift.sysid.common import SisoOptions
from rtlift.sysid.diagnose import clip_levels, diagnose_siso
from rtlift.sysid.identify import identify_siso
from rtlift.sysid.initial import initial_state, steady_state

DATA = Path(__file__).resolve().parents[1] / "rtlift" / "data" / "benchmarks"


def random_model(rng: np.random.Generator, hammerstein: bool) -> SisoModel:
    def tf(n: int) -> HighPassFilter:
        poles = rng.uniform(0.2, 0.95, n) * np.exp(1j * rng.uniform(-0.5, 0.5, n))
        a = np.real(np.poly(np.concatenate([poles, poles.conj()])))
        return HighPassFilter.from_ba(rng.normal(size=3), a)
    knots = np.sort(rng.normal(size=7)) + np.arange(7)
    return SisoModel(tf(2), OutputNonlinearity(knots, np.cumsum(rng.uniform(0.1, 1, 7))),
                     tf(1) if hammerstein else None, 1000.0)


def _steps_equal_chunks(m1, m2, u: np.ndarray, cuts: list[int]) -> np.ndarray:
    """``m1`` stepped over ``u`` equals ``m2`` (its copy) simulated in chunks cut at ``cuts``, to
    1e-12 of the output's scale, outputs and final states; returns the stepped output."""
    stepped = np.array([m1.step(v) for v in u])
    parts, i = [], 0
    for c in cuts:
        parts.append(m2.simulate(u[i:i + c]))
        i += c
    scale = max(1.0, float(np.max(np.abs(stepped))))
    np.testing.assert_allclose(np.concatenate(parts), stepped, atol=1e-12 * scale, rtol=0)
    np.testing.assert_allclose(m1.get_state(), m2.get_state(), atol=1e-12 * scale, rtol=1e-9)
    return stepped


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4), st.booleans())
def test_steps_and_chunks_agree_to_1e12(seed, cuts, hammerstein):
    rng = np.random.default_rng(seed)
    m1 = random_model(rng, hammerstein)
    m2 = model_from_dict(m1.to_dict())
    u = rng.normal(size=sum(cuts)) * 3
    _steps_equal_chunks(m1, m2, u, cuts)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_the_feedback_model_steps_and_chunks_alike_and_round_trips(seed, cuts):
    rng = np.random.default_rng(seed)
    poles = rng.uniform(0.3, 0.9, 2) * np.exp(1j * rng.uniform(0.05, 0.5, 2))
    a = np.real(np.poly(np.concatenate([poles, poles.conj()])))[1:]
    g = rng.normal(size=4)
    # peak gain 0.5 on the unit circle and inputs of 0.1 rms: the loop gain of the feedback
    # (0.5·(2|k2||y| + 3 k3 y²)) stays below one, so the drawn model cannot diverge (a DC-gain
    # normalisation divided by a near-zero Σg for some draws and blew up)
    z = np.exp(-1j * np.linspace(0.0, np.pi, 512))
    peak = np.max(np.abs(np.polyval(g[::-1], z) * z / np.polyval(np.concatenate([[1.0], a])[::-1], z)))
    g *= 0.5 / peak
    # odd seeds: a limit on the state (the recursion clipped inside the loop) at 0.05
    limits = (-np.inf, 0.05) if seed % 2 else (-np.inf, np.inf)
    # every other pair of seeds: an output offset (the operating point the map is centred on)
    # and a direct feedthrough of the input (every other quadruple of seeds)
    offset = rng.uniform(-0.05, 0.05) if seed % 4 >= 2 else 0.0
    # the feedthrough passes through 1/A (y = (b0 u + B v)/A), whose gain is large for poles near
    # the unit circle: drawn against 1/A's l1 gain, so b0 u adds at most 0.05 x the input's peak
    inverse_a = np.zeros(3000)
    for k in range(inverse_a.size):
        inverse_a[k] = (k == 0) - sum(a[i] * inverse_a[k - 1 - i] for i in range(min(k, a.size)))
    b0 = rng.uniform(-0.05, 0.05) / np.sum(np.abs(inverse_a)) if seed % 8 >= 4 else 0.0
    m1 = FeedbackModel(a, g, [rng.uniform(-0.5, 0.5), rng.uniform(0, 2)], 100.0, state_limits=limits,
                       offset=offset, feedthrough=b0)
    m2 = model_from_dict(json.loads(json.dumps(m1.to_dict())))
    assert m2.state_limits == limits and m2.limited == bool(seed % 2) and m2.offset == offset and m2.b0 == b0
    u = rng.normal(size=sum(cuts)) * 0.1
    with np.errstate(over="ignore", invalid="ignore"):
        stepped = np.array([m1.step(v) for v in u])
    # a fourth-order recursion whose state is clipped is not always stable (≈ 1 in 600 limited
    # draws runs away; an unlimited draw never did in 5000): not this property's subject
    assume(not m1.limited or np.all(np.isfinite(stepped)))
    assert np.all(np.isfinite(stepped)) and np.max(stepped) <= limits[1] + 1e-15
    parts, i = [], 0
    for c in cuts:
        state = m2.get_state()
        m2.set_state(state)
        parts.append(m2.simulate(u[i:i + c]))
        i += c
    np.testing.assert_allclose(np.concatenate(parts), stepped, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(m1.get_state(), m2.get_state())


def test_a_feedback_model_file_without_an_offset_loads_as_before():
    """Files written before the output offset and the feedthrough existed have neither: they load
    with none and simulate exactly as the model without them; a model with an offset writes it
    and is shifted by it."""
    m = FeedbackModel([-1.5, 0.7], [0.1, 0.05], [0.2, 1.0], 100.0)
    d = json.loads(json.dumps(m.to_dict()))
    del d["offset"], d["feedthrough"]
    old = model_from_dict(d)
    assert old.offset == 0.0 and old.b0 == 0.0
    u = np.sin(np.arange(300) * 0.1) * 0.1
    np.testing.assert_array_equal(old.simulate(u), m.simulate(u))
    shifted = FeedbackModel(m.a, m.b, m.k, 100.0, offset=0.25)
    assert model_from_dict(shifted.to_dict()).offset == 0.25
    m.reset()
    np.testing.assert_allclose(shifted.simulate(u), 0.25 + m.simulate(u), atol=1e-15, rtol=0)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_a_saturated_model_steps_and_chunks_alike_and_round_trips(seed, cuts):
    rng = np.random.default_rng(seed)
    inner = random_model(rng, bool(seed % 2))
    inner.reset()
    lo, hi = np.quantile(inner.simulate(rng.normal(size=300) * 3), [0.2, 0.8])
    inner.reset()
    u = rng.normal(size=sum(cuts)) * 3
    m1 = SaturatedModel(inner, lo if seed % 3 else -np.inf, hi)
    m2 = model_from_dict(json.loads(json.dumps(m1.to_dict())))
    assert np.max(_steps_equal_chunks(m1, m2, u, cuts)) <= hi


def random_chain(rng: np.random.Generator, limited: bool, fs: float = 0.25) -> StoreChainModel:
    """Two stores with time constants of 3–60 samples about a level of 5, filled by a mean input of 3."""
    level, u_mean = 5.0, 3.0
    t1, t2 = rng.uniform(3, 60, 2) / fs
    p1, p2 = rng.uniform(0.3, 1.2, 2)
    a1, a2 = level ** (1 - p1) / (p1 * t1), level ** (1 - p2) / (p2 * t2)
    params = {"inflow": a1 * level**p1 / u_mean, "outflow_1": a1, "exponent_1": p1,
              "transfer": a2 * level**p2 / (a1 * level**p1), "outflow_2": a2, "exponent_2": p2,
              "brim_1": rng.uniform(5.5, 8.0) if limited else None,
              "ceiling": rng.uniform(6.0, 7.0) if limited else None,
              "spill": rng.uniform(0, 1) if limited else 0.0, "offset": rng.normal()}
    return StoreChainModel(params, fs)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_a_store_chain_steps_and_chunks_alike_and_round_trips(seed, cuts):
    """The plain-float step and the compiled batch run the same arithmetic: equal to 1e-12, and
    the file form (brims as limits on the state, none as null) gives the same model back."""
    rng = np.random.default_rng(seed)
    m1 = random_chain(rng, bool(seed % 2))
    m2 = model_from_dict(json.loads(json.dumps(m1.to_dict())))
    assert m2.params == m1.params and m2.limited == bool(seed % 2)
    u = np.abs(3.0 + 3.0 * rng.normal(size=sum(cuts)))
    stepped = _steps_equal_chunks(m1, m2, u, cuts)
    if seed % 2:
        assert np.max(stepped) <= m1.params["ceiling"] and m1.limits()["upper"] == m1.params["ceiling"]


def test_a_two_tank_rig_that_overflows_is_diagnosed_as_a_store_chain_at_its_brim():
    """Known answer: two stores in cascade with Torricelli outflows (exponents ½), the upper one
    spilling into the lower, the lower one's gauge topping out at its brim (+ 0.5 % noise). From
    a Wiener model the diagnosis sees the output pile up at the brim and accepts ``saturation``
    in the store-chain form, with the exponents and the ceiling found, and the validation error
    falls to about the noise (0.04; the Wiener model misses by five times that)."""
    rng = np.random.default_rng(5)
    fs, n = 0.25, 3000
    steps = np.repeat(rng.uniform(0.5, 6.0, n // 25 + 1), 25)[:n]
    u = steps + 0.2 * rng.normal(size=n)
    truth = {"inflow": 0.035, "outflow_1": 0.06, "exponent_1": 0.5, "transfer": 1.0, "outflow_2": 0.05,
             "exponent_2": 0.5, "brim_1": 12.0, "ceiling": 8.0, "spill": 0.5, "offset": 1.0}
    plant = StoreChainModel(truth, fs)
    y = np.minimum(plant.simulate(u) + 0.04 * rng.normal(size=n), truth["ceiling"])
    assert 0.01 < np.mean(y >= truth["ceiling"]) < 0.2               # it overflows now and then

    def rec(lo: int, hi: int, name: str) -> SisoRecord:
        return SisoRecord(np.arange(hi - lo) / fs, u[lo:hi], y[lo:hi], {"fs_hz": repr(fs)}, name)
    train, val = rec(0, 1500, "train"), rec(1450, 3000, "val")
    opt = SisoOptions(orders=(2,), feedback_orders=(2,), max_nfev=300)
    wiener = identify_siso(train, "wiener", options=opt)
    report, augmented = diagnose_siso(wiener, train, [val], skip=50, options=opt)
    sat = next(e for e in report["effects"] if e["name"] == "saturation")
    assert sat["accepted"], sat["evidence"]
    assert sat["params"]["model"] == "store_chain" and sat["params"]["where"] == "state"
    assert sat["params"]["upper"] == truth["ceiling"]
    assert isinstance(augmented, StoreChainModel)
    p = augmented.params
    # found: 0.498 / 0.502, 0.050, 0.99 (x₁'s scale is not observable: inflow and transfer trade)
    assert abs(p["exponent_1"] - 0.5) < 0.05 and abs(p["exponent_2"] - 0.5) < 0.05
    assert p["outflow_2"] == pytest.approx(0.05, rel=0.1) and abs(p["offset"] - 1.0) < 0.05
    assert sat["validation_rmse_after"] < 0.06 < 0.3 * sat["validation_rmse_before"]   # 0.042 vs 0.223


def test_on_cascaded_tanks_the_diagnosis_fills_two_stores_that_overflow(tmp_path):
    """The measured Cascaded Tanks through the command line as ``benchmarks/realdata.py`` runs it:
    the estimation data's first 80 % to identify, the rest (from 50 samples earlier) to
    validate, the official test split to score (free run from the state estimated on the first
    50 samples, which are unscored: ``--init-state``). A Wiener model misses by 1.4 V; the level
    piles up at the 10 V ceiling, and the store chain with that ceiling (the two tanks, overflow)
    reaches 0.24 V (published: grey box 0.191, CT SUBNET 0.306, PNLSS 0.45)."""
    d = np.load(DATA / "cascaded_tanks.npz")
    fs = 1.0 / float(d["Ts"])
    n = int(round(0.8 * d["u_est"].size))
    parts = {"est": (d["u_est"][:n], d["y_est"][:n]), "val": (d["u_est"][n - 50:], d["y_est"][n - 50:]),
             "test": (d["u_test"], d["y_test"])}
    for name, (u, y) in parts.items():
        write_siso_record(tmp_path / f"{name}.csv", SisoRecord(np.arange(u.size) / fs, u, y, {"fs_hz": repr(fs)}, name))
    assert main(["identify", "--record", str(tmp_path / "est.csv"), "-o", str(tmp_path / "m.json")]) == 0
    assert main(["diagnose", "--model", str(tmp_path / "m.json"), "--train", str(tmp_path / "est.csv"),
                 "--validate", str(tmp_path / "val.csv"), "--skip", "50", "--init-state",
                 "--out", str(tmp_path / "d")]) == 0
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    sat = next(e for e in report["effects"] if e["name"] == "saturation")
    assert sat["accepted"] and sat["params"]["model"] == "store_chain" and sat["params"]["upper"] == 10.0
    rmse = {}
    for which, model in (("before", tmp_path / "m.json"), ("after", tmp_path / "d" / "model_augmented.json")):
        assert main(["validate", "--model", str(model), str(tmp_path / "test.csv"), "--skip", "50", "--init-state",
                     "--json", str(tmp_path / f"{which}.json")]) == 0
        rmse[which] = json.loads((tmp_path / f"{which}.json").read_text())["records"]["test"]["rmse"]
    assert rmse["before"] > 1.0                                    # 1.37 V
    assert rmse["after"] < 0.28                                    # 0.243 V (0.312 V from rest, x0 not fitted)


def test_the_initial_state_of_a_store_chain_that_starts_full_is_found_on_the_first_samples():
    """A record that starts with the stores full (at the steady state of a past input of 5): from
    rest the model first has to fill them; the state estimated on the first 50 samples (a steady
    state of the model's own) follows the record from there on."""
    rng = np.random.default_rng(4)
    plant = random_chain(rng, False)
    plant.set_state(steady_state(plant, 5.0))
    u = np.abs(2.0 + rng.normal(size=400))
    y = plant.simulate(u)
    plant.reset()
    from_rest = plant.simulate(u)
    x0 = initial_state(plant, u, y, 50)
    plant.reset()
    plant.set_state(x0)
    after = plant.simulate(u)
    assert np.max(np.abs(after - y)[50:]) < 1e-3 < 0.1 < np.max(np.abs(from_rest - y)[50:])


def test_finer_knots_are_kept_only_where_they_lower_the_held_out_error():
    """A Wiener system with a sharp kink in its map: 4 knots cannot follow it, the refinement on 16
    (``more_knots``) can and is kept; the knots used are in the provenance, and the model file
    round-trips."""
    rng = np.random.default_rng(11)
    n = 4000
    u = rng.normal(size=n)
    x = np.linspace(-4, 4, 9)
    true = SisoModel(HighPassFilter.from_ba([0.3, 0.2], [1.0, -0.5]), OutputNonlinearity(x, x + 1.5 * np.abs(x)), None,
                     100.0)
    y = true.simulate(u) + 0.01 * rng.normal(size=n)
    rec = SisoRecord(np.arange(n) / 100.0, u, y, {"fs_hz": "100.0"}, "kink")
    coarse = identify_siso(rec, "wiener", options=SisoOptions(orders=(1,), knots=4, more_knots=(), max_nfev=100))
    fine = identify_siso(rec, "wiener", options=SisoOptions(orders=(1,), knots=4, more_knots=(16,), max_nfev=100))
    assert coarse.provenance["knots"] == 4 and fine.provenance["knots"] == 16
    assert fine.metrics["holdout_rmse"] < 0.5 * coarse.metrics["holdout_rmse"]
    back = model_from_dict(json.loads(json.dumps(fine.to_dict())))
    np.testing.assert_array_equal(back.simulate(u[:500]), fine.simulate(u[:500]))


def test_clip_levels_are_where_the_measurement_piles_up():
    rng = np.random.default_rng(3)
    y = np.sin(np.linspace(0, 60, 4000)) + 0.01 * rng.normal(size=4000)
    assert clip_levels(y)[0] == (-np.inf, np.inf)               # a maximum reached once is no limit
    (lo, hi), detail = clip_levels(np.clip(y, -2.0, 0.7))
    assert (lo, hi) == (-np.inf, 0.7) and "at the maximum 0.7" in detail
    assert clip_levels(np.clip(y, -0.9, 0.7))[0] == (-0.9, 0.7)
    few = y.copy()
    few[:4] = 5.0                                                  # 4 samples: below the 5-sample floor
    assert clip_levels(few)[0] == (-np.inf, np.inf)


def test_a_clipped_wiener_hammerstein_system_is_diagnosed_as_saturation(tmp_path):
    """u → G₁ → tanh → G₂ → clip at its 90th percentile (+ sensor noise before the clip): from a
    Wiener model, the diagnosis finds the level the output piles up at, re-identifies each form
    with the clip in place and accepts the saturated Wiener–Hammerstein model."""
    rng = np.random.default_rng(7)
    p = 0.9 * np.exp(0.3j)
    x = np.linspace(-3, 3, 7)
    true = SisoModel(HighPassFilter.from_ba([0.05, 0.05], np.real(np.poly([p, p.conjugate()]))),
                     OutputNonlinearity(x, np.tanh(x)), HighPassFilter.from_ba([0.3], [1.0, -0.7]), 100.0)
    u = np.zeros(3000)
    for k in range(1, u.size):                                     # AR(1) input, coloured like the benchmarks'
        u[k] = 0.5 * u[k - 1] + rng.normal()
    free = true.simulate(u)
    level = float(np.quantile(free, 0.9))
    y = np.minimum(free + 1e-3 * np.std(free) * rng.normal(size=u.size), level)

    def rec(lo: int, hi: int, name: str) -> SisoRecord:
        return SisoRecord(np.arange(hi - lo) / 100.0, u[lo:hi], y[lo:hi], {}, name)
    opt = SisoOptions(orders=(3,), feedback_orders=(2,), max_nfev=100)
    train, val = rec(0, 2000, "train"), rec(2000, 3000, "val")
    wiener = identify_siso(train, "wiener", options=opt)
    report, augmented = diagnose_siso(wiener, train, [val], skip=50, options=opt)
    assert [e["name"] for e in report["effects"] if e["accepted"]] == ["saturation"]
    sat = report["effects"][2]
    assert sat["params"]["upper"] == level and sat["params"]["lower"] is None
    assert sat["params"]["model"] == "wiener_hammerstein"
    assert sat["validation_rmse_after"] < 0.15 * sat["validation_rmse_before"]   # 0.041 -> 0.0034
    assert isinstance(augmented, SaturatedModel) and augmented.upper == level
    (tmp_path / "m.json").write_text(json.dumps(augmented.to_dict()))
    back = model_from_dict(json.loads((tmp_path / "m.json").read_text()))
    np.testing.assert_array_equal(back.simulate(val.u), augmented.simulate(val.u))


def test_a_store_that_overflows_is_diagnosed_as_a_limit_on_the_state():
    """A first-order store with a quadratic outflow whose level cannot pass its brim:
    y(k) = min(0.9 y(k−1) + 0.1 v(k−1), brim), v = u − 0.3 y² (+ a gauge's noise, the gauge
    topping out at the brim). The
    output piles up at the brim; an output clip would let the level wind up beyond it and lag
    on the way down, the state limit does not: from a Wiener model the diagnosis accepts
    ``saturation`` with the limit on the state, at the brim, and the error falls to the noise."""
    rng = np.random.default_rng(11)
    u = np.zeros(6000)
    for k in range(1, u.size):
        u[k] = 0.8 * u[k - 1] + 0.5 * rng.normal()
    u += 1.0
    plant = FeedbackModel([-0.9], [0.1], [0.3, 0.0], 1.0)
    free = plant.simulate(u)
    brim = float(np.quantile(free, 0.85))
    plant = FeedbackModel([-0.9], [0.1], [0.3, 0.0], 1.0, state_limits=(-np.inf, brim))
    noise = 0.002
    y = plant.simulate(u)
    y = np.minimum(y + noise * rng.normal(size=u.size), brim)          # the gauge tops out at the brim

    def rec(lo: int, hi: int, name: str) -> SisoRecord:
        return SisoRecord(np.arange(hi - lo), u[lo:hi], y[lo:hi], {"fs_hz": "1.0"}, name)
    opt = SisoOptions(orders=(1, 2), feedback_orders=(1, 2), max_nfev=200)
    train, val = rec(0, 2000, "train"), rec(1950, 6000, "val")
    wiener = identify_siso(train, "wiener", options=opt)
    report, augmented = diagnose_siso(wiener, train, [val], skip=50, options=opt)
    sat = next(e for e in report["effects"] if e["name"] == "saturation")
    assert sat["accepted"], sat["evidence"]
    assert sat["params"]["where"] == "state" and sat["params"]["upper"] == brim
    assert sat["params"]["model"] == "nonlinear_feedback"
    assert isinstance(augmented, FeedbackModel) and augmented.limited
    assert sat["validation_rmse_after"] < 3 * noise < sat["validation_rmse_before"]
    assert report["not_built"] == []


def test_a_generic_record_round_trips_and_a_bad_one_is_one_line(tmp_path):
    rec = SisoRecord(np.arange(5) / 10.0, np.arange(5.0), -np.arange(5.0), {"fs_hz": "10"}, "r")
    write_siso_record(tmp_path / "r.csv", rec)
    back = read_siso_record(tmp_path / "r.csv")
    assert back.fs_hz == 10.0 and np.array_equal(back.y, rec.y)
    (tmp_path / "bad.csv").write_text("t,u\n0,1\n")
    with pytest.raises(RecordError, match="column 'y' is missing"):
        read_siso_record(tmp_path / "bad.csv")


def test_a_model_refuses_records_of_the_other_kind_with_one_line(tmp_path, capsys):
    rng = np.random.default_rng(1)
    m = random_model(rng, False)
    (tmp_path / "m.json").write_text(json.dumps(m.to_dict()))
    lift = tmp_path / "lift.csv"
    lift.write_text("t,cmu,cmu_envelope,dcl\n0,0,0,0\n0.0025,0,0,0\n0.005,0,0,0\n")
    assert main(["validate", "--model", str(tmp_path / "m.json"), str(lift)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "lift record" in err


def test_init_state_needs_the_samples_it_is_estimated_on(tmp_path, capsys):
    m = random_model(np.random.default_rng(1), False)
    (tmp_path / "m.json").write_text(json.dumps(m.to_dict()))
    u = np.sin(np.arange(200) * 0.1)
    write_siso_record(tmp_path / "r.csv", SisoRecord(np.arange(200) / m.fs_hz, u, u, {"fs_hz": repr(m.fs_hz)}, "r"))
    assert main(["validate", "--model", str(tmp_path / "m.json"), str(tmp_path / "r.csv"), "--init-state"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--skip N > 0" in err
    assert main(["validate", "--model", str(tmp_path / "m.json"), str(tmp_path / "r.csv"), "--init-state",
                 "--skip", "50"]) == 0


@pytest.mark.parametrize("command", ["observe", "control", "replay"])
def test_a_live_command_given_a_generic_model_says_it_needs_a_lift_model(command, tmp_path, capsys):
    m = random_model(np.random.default_rng(2), False)
    (tmp_path / "m.json").write_text(json.dumps(m.to_dict()))
    link = {"observe": ["--serial", "loop://"], "control": ["--serial", "loop://", "--reference", "steps:0.1@0"],
            "replay": [str(tmp_path / "none.bin")]}[command]
    assert main([command, *link, "--model", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an rtlift model file" not in err
    assert "generic t,u,y record" in err and "need a hybrid lift model" in err and "validate and diagnose" in err


@pytest.fixture(scope="module")
def wh2009():
    d = np.load(DATA / "wh2009.npz")
    a, b = (int(v) for v in d["official_slice"])
    u, y, n = d["u"][a:b], d["y"][a:b], int(d["n_train"])
    fs = float(d["fs"])

    def rec(lo: int, hi: int, name: str) -> SisoRecord:
        return SisoRecord(np.arange(hi - lo) / fs, u[lo:hi], y[lo:hi], {"fs_hz": repr(fs)}, name)
    # a shortened estimation (10 000 samples: 0.296 mV on the test, 29.5 s of CPU; 16 000 gave
    # 0.287 mV in 125 s, 32 000 took 185 s) to keep the suite quick; benchmarks/realdata.py runs
    # the official estimation data
    return rec(0, 10000, "est"), rec(10000, 15000, "val"), rec(n, u.size, "test")


def test_on_wh2009_the_residual_leads_from_a_wiener_model_to_the_output_block_it_lacks(wh2009):
    est, val, test = wh2009
    # default options: the splits' ranking by their linear start is not reliable — the right
    # split (three poles in each block) ranks third here and only the full refinement of the
    # three best finds it (4.5 mV otherwise: a local minimum of the other splits)
    opt = SisoOptions()
    wiener = identify_siso(est, "wiener", options=opt)
    report, augmented = diagnose_siso(wiener, est, [val], skip=50, options=opt)
    entry = report["effects"][0]
    assert (entry["name"], entry["kind"], entry["accepted"]) == ("output_dynamics", "structure", True)
    assert report["effects"][2]["evidence"].startswith("not tried: no clipping level")  # nothing piles up
    assert "bv_u2_e (significant)" in entry["evidence"]           # Billings-Voon pointed there
    rmse = {}
    for name, model in (("wiener", wiener), ("wh", augmented)):
        model.reset()
        rmse[name] = 1e3 * float(np.sqrt(np.mean((model.simulate(test.u) - test.y)[50:] ** 2)))
    assert rmse["wiener"] > 25.0                                   # ≈ 35 mV, the known Wiener level
    assert rmse["wh"] < 1.0                      # 0.296 mV here; full estimation data (realdata): 0.279 mV
    assert report["augmented"]["records"]["val"]["rmse"] < 0.1 * report["baseline"]["records"]["val"]["rmse"]
    b, a = augmented.g2.ba
    assert np.all(np.abs(np.roots(a)) < 1) and augmented.structure == "wiener_hammerstein"
    np.testing.assert_allclose(np.sum(augmented.g1.ba[0]) / np.sum(augmented.g1.ba[1]), 1.0, rtol=1e-9)


def tanks_case(d: Path) -> tuple[Path, Path, Path]:
    """The Cascaded Tanks 1024-sample estimation record split at 820 into ``d/est.csv`` and
    ``d/val.csv``, and ``rtlift identify``'s Wiener model of the first part, ``d/m.json``."""
    data = np.load(DATA / "cascaded_tanks.npz")
    fs = 1.0 / float(data["Ts"])
    u, y = data["u_est"], data["y_est"]
    for name, lo, hi in (("est", 0, 820), ("val", 820, 1024)):
        write_siso_record(d / f"{name}.csv",
                          SisoRecord(np.arange(hi - lo) / fs, u[lo:hi], y[lo:hi], {"fs_hz": repr(fs)}, name))
    assert main(["identify", "--record", str(d / "est.csv"), "-o", str(d / "m.json")]) == 0
    return d / "m.json", d / "est.csv", d / "val.csv"


def test_the_command_line_identifies_diagnoses_and_validates_a_generic_record(tmp_path, capsys):
    """Cascaded tanks (1024 samples): identify, then validate --skip reproduces the diagnosis's scores."""
    tanks_case(tmp_path)
    assert main(["diagnose", "--model", str(tmp_path / "m.json"), "--train", str(tmp_path / "est.csv"),
                 "--validate", str(tmp_path / "val.csv"), "--skip", "50", "--out", str(tmp_path / "d")]) == 0
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert main(["validate", "--model", str(tmp_path / "d" / "model_augmented.json"), str(tmp_path / "val.csv"),
                 "--skip", "50", "--json", str(tmp_path / "v.json"), "--figures", str(tmp_path / "figs")]) == 0
    assert [p.name for p in (tmp_path / "figs").iterdir()] == ["val.png"]          # a figure per record
    assert (tmp_path / "figs" / "val.png").stat().st_size > 10_000
    scored = json.loads((tmp_path / "v.json").read_text())["records"]["val"]
    assert scored["rmse"] == pytest.approx(report["augmented"]["records"]["val"]["rmse"], rel=1e-12)
    names = [e["name"] for e in report["effects"]]
    assert names == ["output_dynamics", "nonlinear_feedback", "saturation"]
    sat = report["effects"][2]
    # the sensor's 10 V ceiling is found, and the clipped model lowers the validation error by
    # about two thirds; but 205 validation samples make 3 blocks of 50, too few for t >= 3
    assert sat["params"]["upper"] == 10.0 and sat["params"]["lower"] is None
    assert sat["validation_rmse_after"] < 0.5 * sat["validation_rmse_before"]
    assert not sat["accepted"] and "over 3 blocks" in sat["evidence"]
    assert main(["identify", "--record", str(tmp_path / "est.csv"), "--static", "x.csv", "-o", "m.json"]) == 2
    assert main(["identify", "-o", "m.json"]) == 2
    assert capsys.readouterr().err.count("rtlift: error:") == 2


def test_on_silverbox_the_diagnosis_feeds_the_output_back_through_a_cubic(tmp_path):
    """Silverbox (a Duffing oscillator): a Wiener model's ≈ 14 mV on the arrow becomes ≈ 1 mV."""
    d = np.load(DATA / "silverbox_SNLS80mV.npz")
    u, y, fs = d["V1"], d["V2"], float(d["fs"])

    def rec(lo: int, hi: int, name: str) -> SisoRecord:
        return SisoRecord(np.arange(hi - lo) / fs, u[lo:hi], y[lo:hi], {"fs_hz": repr(fs)}, name)
    # estimation shortened to 20 000 of the official 65 063 multisine samples, 6 000 to validate
    # (0.361 mV on the arrow, 65 s of CPU; 32 000 + 8 000 gave 0.365 mV in 76 s; realdata.py: all)
    est, val, test = rec(40650, 60650, "est"), rec(60650, 66650, "val"), rec(100, 40575, "arrow")
    # default options: the splits' ranking by their linear start is not reliable — the right
    # split (three poles in each block) ranks third here and only the full refinement of the
    # three best finds it (4.5 mV otherwise: a local minimum of the other splits)
    opt = SisoOptions()
    wiener = identify_siso(est, "wiener", options=opt)
    report, augmented = diagnose_siso(wiener, est, [val], skip=50, options=opt)
    accepted = [e["name"] for e in report["effects"] if e["accepted"]]
    assert accepted == ["nonlinear_feedback"] and augmented.structure == "nonlinear_feedback"
    assert augmented.k[1] > 1.0                                    # a hardening cubic stiffness
    rmse = {}
    for name, model in (("wiener", wiener), ("feedback", augmented)):
        model.reset()
        rmse[name] = 1e3 * float(np.sqrt(np.mean((model.simulate(test.u) - test.y)[50:] ** 2)))
    assert rmse["wiener"] > 8.0                                    # ≈ 14 mV, a Wiener model's level
    assert rmse["feedback"] < 1.5                                  # 0.40 mV with the full estimation data

"""``--gust F:A,...`` (hil_sim.gust): a lift disturbance added to the truth plant's ΔCL, with
known answers — the bench with a gust minus the same bench (same seed) without it is exactly
Σ A sin(2π F t) in the truth, and the same sine (to the ADC's quantisation) in the measured
lift; a bad spec is one line and exit 2."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil_sim.experiments import run_experiment
from hil_sim.gust import Gust, parse_gust
from hil_sim.hil import HilStream
from rtlift.app.cli import main
from rtlift.core.errors import UserError

FS = 400
SPEC = "0.35:0.01,1.5:0.004"


def _sines(t: np.ndarray) -> np.ndarray:
    return 0.01 * np.sin(2 * math.pi * 0.35 * t) + 0.004 * np.sin(2 * math.pi * 1.5 * t)


def test_the_gust_adds_exactly_its_sines_to_the_true_lift():
    plain = run_experiment("sine_k0125", seed=2)
    gusty = run_experiment("sine_k0125", seed=2, gust=parse_gust(SPEC))
    np.testing.assert_allclose(gusty.dcl_true - plain.dcl_true, _sines(plain.t), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(gusty.cmu, plain.cmu)  # the actuation does not change
    assert gusty.meta["gust"] == SPEC


def test_the_measured_lift_carries_the_gust():
    plain = run_experiment("random", seed=3).to_record()
    gusty = run_experiment("random", seed=3, gust=parse_gust(SPEC)).to_record()
    diff = gusty.dcl - plain.dcl
    # the same noise (same seed): the difference is the gust, a constant (the 2 s tare saw part
    # of the gust) and the counts' quantisation (one ADC step ≈ 0.004 ΔCL: two roundings give
    # σ ≈ step / √6 ≈ 0.0016)
    (gain, offset), *_ = np.linalg.lstsq(np.c_[_sines(plain.t), np.ones(len(diff))], diff, rcond=None)
    assert gain == pytest.approx(1.0, abs=2e-3)
    assert np.std(diff - gain * _sines(plain.t) - offset) < 0.002


def test_the_hil_stream_truth_carries_the_gust_on_the_device_clock():
    def truth(gust):
        stream = HilStream("random", seed=4, gust=gust)
        it = iter(stream)
        for _ in range(3 * FS // 50):
            next(it)
        return stream.truth_array()

    idx, plain = truth(None)
    idx2, gusty = truth(parse_gust("0.5:0.02"))
    np.testing.assert_array_equal(idx, idx2)
    np.testing.assert_allclose(gusty - plain, 0.02 * np.sin(2 * math.pi * 0.5 * idx / FS), atol=1e-12)


def test_a_spec_round_trips_and_empty_is_no_gust():
    g = parse_gust(" 0.1:0.01 , 2:0.005")
    assert g.lines == ((0.1, 0.01), (2.0, 0.005)) and parse_gust(g.spec()) == g
    assert not parse_gust(None) and not parse_gust("") and not Gust()


@pytest.mark.parametrize("spec", ["0.1", "0.1:x", "a:0.01", "0:0.01", "-1:0.01", "250:0.01", "0.1:0",
                                  "0.1:-0.01", "0.1:nan", "inf:0.01", "0.1:2", "0.1:0.01,"])
def test_a_bad_gust_is_one_line(spec):
    with pytest.raises(UserError) as exc:
        parse_gust(spec)
    assert "\n" not in str(exc.value) and "--gust" in str(exc.value)


def test_bench_commands_refuse_a_bad_gust_with_exit_2(tmp_path, capsys):
    assert main(["bench", "record", "static", "--out", str(tmp_path / "x.csv"), "--gust", "0.1:abc"]) == 2
    assert main(["bench", "serve", "--serial", "--gust", "0:0.01"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all("--gust" in line for line in err)
    assert not (tmp_path / "x.csv").exists()

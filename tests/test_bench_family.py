"""The plant family (hil_sim.family, docs/BENCH.md "A family of plants"): draw 0 is our bench byte
for byte, draws are reproducible and within their ranges, the calibration draws 1–49 stay
physically plausible, and a draw streams and records as one plant."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from hil_sim import FS_HZ
from hil_sim.experiments import daq_stream, run_experiment, write_bench_record
from hil_sim.family import (
    CALIBRATION_DRAWS,
    RANGES,
    REPORTING_DRAWS,
    draws_line,
    plant_draw,
    properties,
    static_lift,
)
from hil_sim.hil import HilStream
from hil_sim.plant import PlantParams
from hil_sim.sensors import SensorParams
from rtlift.app.cli import main
from rtlift.core.records import read_record

TODAY = {
    # sha256 of `rtlift bench record` CSVs written at commit 460a998, before the family existed
    ("single_burst", 0): "9212d175bee8aa69b417e9d3be7afe582e6d97b24cbfa019ebc96efb06f3b92a",
    ("train_T7", 3): "b53f533d73c996de9be96c1d9be77082ed1cb2739a19515fd5b52cd9a9a9fc0d",
}


@pytest.mark.parametrize("name,seed", sorted(TODAY))
def test_draw_0_records_todays_bench_byte_for_byte(tmp_path, name, seed):
    for i, run in enumerate((run_experiment(name, seed=seed), run_experiment(name, seed=seed, plant_draw=0))):
        path = tmp_path / f"{i}.csv"
        write_bench_record(run, path)
        assert hashlib.sha256(path.read_bytes()).hexdigest() == TODAY[(name, seed)]


def test_draw_0_is_the_default_parameters_and_the_protocol_sets_are_disjoint():
    d = plant_draw(0)
    assert d.plant == PlantParams() and d.sensor == SensorParams()
    assert set(CALIBRATION_DRAWS) == set(range(1, 50)) and set(REPORTING_DRAWS) == set(range(100, 200))
    assert draws_line(list(range(100, 120))) == "plant draws: 100-119 (reporting)"
    assert draws_line([1, 2, 3, 7]) == "plant draws: 1-3,7 (calibration)"


def test_draws_are_reproducible_distinct_within_their_ranges_and_spread_over_them():
    values = np.array([list(plant_draw(n).values().values()) for n in CALIBRATION_DRAWS])
    assert plant_draw(7) == plant_draw(7) and plant_draw(7) != plant_draw(8)
    lo = np.array([r.lo for r in RANGES.values()])
    hi = np.array([r.hi for r in RANGES.values()])
    assert np.all(values >= lo) and np.all(values <= hi)
    # 49 uniform draws cover most of each range (the chance one covers < 70 % is < 1e-6)
    spread = (values.max(axis=0) - values.min(axis=0)) / (hi - lo)
    assert spread.min() > 0.7, dict(zip(RANGES, spread.round(2), strict=True))


def test_calibration_draws_stay_physically_plausible():
    """docs/BENCH.md's properties, noise-free, on every calibration draw (and draw 0 as the check
    that the measure reads our bench as BENCH.md says)."""
    props = {n: properties(n) for n in (0, *CALIBRATION_DRAWS)}
    col = {k: np.array([p[k] for p in props.values()]) for k in props[0]}
    assert abs(col["full"][0] - 0.218) < 0.003 and abs(col["burst_peak"][0] - 0.024) < 0.001   # BENCH.md
    assert np.all((col["full"] > 0.12) & (col["full"] < 0.3)), col["full"]    # ΔCL at full Cμ, 8 Hz: 0.1–0.3
    assert np.all((col["half_over_full"] > 0.5) & (col["half_over_full"] < 0.75))   # concave ...
    assert np.all(col["slope_ratio"] > 1.2), col["slope_ratio"]               # ... and saturating
    low = np.array([static_lift(plant_draw(n).plant, c) for n in (3, 31) for c in (0.004, 0.008, 0.012)])
    assert np.all(np.diff(low.reshape(2, 3)) > 0)                              # rising from the start
    assert np.all((col["burst_peak"] > 0.01) & (col["burst_peak"] < 0.05))     # single burst at 60 V
    assert np.all((col["burst_peak_tplus"] > 0.8) & (col["burst_peak_tplus"] < 2.2))   # 1–2 t⁺ after it
    assert np.all(col["burst_dip"] < 0.0)                                      # the initial dip
    assert np.all(col["burst_tail"] < 0.3), col["burst_tail"]                  # a transient of a few t⁺


def test_a_draw_streams_as_one_plant_and_its_record_says_its_draw(tmp_path):
    run = run_experiment("train_T1p75", seed=2, plant_draw=7)
    n = len(run)
    chunks = daq_stream("train_T1p75", seed=2, plant_draw=7)
    parts = [next(chunks) for _ in range(int(np.ceil(n / FS_HZ)))]
    dcl = np.concatenate([p.dcl_true for p in parts])[:n]
    counts = np.concatenate([p.counts for p in parts])[:n]
    assert np.max(np.abs(dcl - run.dcl_true)) < 1e-12
    assert np.max(np.abs(counts - run.counts)) <= 1      # filters' state carried: ≤ one count of rounding
    sensed = np.concatenate([p.dcl_sensed for p in parts])[:n]
    assert np.max(np.abs(sensed - run.dcl_sensed)) < 1e-12
    stream = HilStream("train_T1p75", seed=2, plant_draw=7)
    hil = np.concatenate([p.dcl_true for p, _ in zip(stream, range(40), strict=False)])
    assert np.max(np.abs(hil - run.dcl_true[:len(hil)])) < 1e-12
    rec = run.to_record()
    assert rec.meta["plant_draw"] == "7"
    other = run_experiment("train_T1p75", seed=2).to_record()
    assert np.max(np.abs(rec.extra["dcl_true"] - other.extra["dcl_true"])) > 0.01   # another plant
    noise = rec.dcl - rec.extra["dcl_sensed"]       # the measurement chain's noise, its filtering aside
    assert 0.002 < noise.std() < 0.008 and np.corrcoef(rec.dcl, rec.extra["dcl_sensed"])[0, 1] > 0.9
    # the chain smooths the burst vortex's sharp onset: the record is closer to the lift as sensed
    assert (rec.dcl - rec.extra["dcl_true"]).std() > noise.std()
    assert "dcl_sensed" not in other.extra                     # our bench: a rigid balance, no filter


def test_cli_record_with_a_plant_draw_and_a_bad_draw(tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["bench", "record", "single_burst", "--plant-draw", "101", "--out", str(out)]) == 0
    assert read_record(out).meta["plant_draw"] == "101"
    assert "plant draw 101" in capsys.readouterr().out
    assert main(["bench", "record", "single_burst", "--plant-draw", "-1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plant draw must be a non-negative integer" in err[0]


def test_a_family_run_on_a_local_cluster_equals_the_serial_run_and_resumes(tmp_path):
    """benchmarks/family.py's runner on a tiny task set (each draw's BENCH.md properties)."""
    from distributed import LocalCluster

    from benchmarks.family import run_tasks

    tasks = [(n,) for n in (1, 2, 3, 4)]
    serial = run_tasks(properties, tasks, tmp_path / "serial.jsonl", serial=True, progress=False)
    assert serial[2] == properties(3) and serial[0]["full"] != serial[1]["full"]
    on_cluster = tmp_path / "cluster.jsonl"
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0") as cluster:  # as --scheduler
        at = cluster.scheduler_address
        run_tasks(properties, tasks[:2], on_cluster, scheduler=at, progress=False)     # killed halfway ...
        first = on_cluster.read_text().splitlines()
        assert run_tasks(properties, tasks, on_cluster, scheduler=at, progress=False) == serial   # ... restarted
    lines = on_cluster.read_text().splitlines()
    assert len(lines) == 4 and lines[:2] == first       # the two finished tasks were not redone

    calls = []

    def counted(n: int) -> dict[str, float]:
        calls.append(n)
        return properties(n)

    resumed = tmp_path / "resumed.jsonl"
    run_tasks(counted, tasks[:2], resumed, serial=True, progress=False)
    with open(resumed, "a") as f:
        f.write('{"key": "[3]", "resu')                # the kill tore the third task's line
    calls.clear()
    assert run_tasks(counted, tasks, resumed, serial=True, progress=False) == serial
    assert calls == [3, 4]

"""``benchmarks/null_rate.py``'s plan and bound (no diagnosis runs here): the closed-loop
training type gets its own noise seed per run, naming and reference balanced and not tied to
each other; the Clopper–Pearson bound is the textbook one."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from benchmarks.null_rate import ALL_TYPES, CLOSED_LOOP, CLOSED_LOOP_REFERENCES, clopper_pearson, main, plan, unnamed
from rtlift.core.records import Record


def test_closed_loop_runs_get_their_own_seed_and_balanced_naming_and_references():
    jobs = plan(8, 300, list(ALL_TYPES), twins=6, independent=None)
    assert len(jobs) == 8 * 4
    cl = [j for j in jobs if j["train"] == CLOSED_LOOP]
    assert len(cl) == 8
    assert all(len(j["noise_seeds"]) == 1 and not j["twin"] for j in cl)
    seeds = [s for j in jobs for s in j["noise_seeds"]]
    assert len(seeds) == len(set(seeds))                      # no record shares a noise realisation
    for t in ALL_TYPES:
        assert Counter(j["naming"] for j in jobs if j["train"] == t) == {"named": 4, "unnamed": 4}
    # every reference with both namings, twice each: the input varies independently of the name
    assert Counter((j["reference"], j["naming"]) for j in cl) == \
        {(r, n): 2 for r in CLOSED_LOOP_REFERENCES for n in ("named", "unnamed")}
    # the twins (same records, other naming) stay on the open-loop types
    assert [j["train"] for j in jobs if j["twin"]] == ["sine_k0125", "sine_k025", "random", "sine_k0125", "sine_k025"]


def test_clopper_pearson_upper_bound_with_no_false_effect():
    lo, hi = clopper_pearson(0, 213)
    assert lo == 0.0
    assert hi == pytest.approx(1.0 - 0.025 ** (1.0 / 213), rel=1e-9)     # 1.7 %
    lo, hi = clopper_pearson(2, 100)
    assert 0.0024 < lo < 0.0025 and 0.070 < hi < 0.071                    # the tabulated 0.24 %–7.04 %


def test_unnamed_drops_what_names_the_experiment():
    rec = Record(np.arange(3) / 400.0, np.zeros(3), np.zeros(3), np.zeros(3),
                 {"experiment": "random", "seed": "5", "source": "x.bin", "loop": "control"}, {}, "closed_loop")
    u = unnamed(rec, "run_a")
    assert u.name == "run_a" and u.meta == {"loop": "control"}


def test_unknown_type_is_one_line_and_exit_2(capsys):
    assert main(["--types", "sine_k0125,closed_loops", "--seeds", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "closed_loop" in err


def test_summary_bounds_each_training_type_on_its_own(capsys):
    import json

    from benchmarks.null_rate import summarize

    runs = [{"plant": "bench", "train": "closed_loop", "naming": "named", "effects": [], "structure": []}] * 30 + \
        [{"plant": "bench", "train": "random", "naming": "named", "effects": ["delay"], "structure": []}] + \
        [{"plant": "bench", "train": "random", "naming": "unnamed", "effects": [], "structure": []}] * 19
    summarize(runs, None, 0.0)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["clean_runs"] == 50 and out["false_effects"] == 1 and out["planned_runs"] is None
    assert out["upper_95"] == pytest.approx(clopper_pearson(1, 50)[1])
    cl, rnd = out["by"]["bench:closed_loop"], out["by"]["bench:random"]
    assert cl["runs"] == 30 and cl["upper_95"] == pytest.approx(1 - 0.025 ** (1 / 30))   # 11.6 %
    assert rnd["runs_with_false_effect"] == 1 and rnd["upper_95"] == pytest.approx(clopper_pearson(1, 20)[1])


def test_a_failed_run_is_listed_and_not_counted_as_a_diagnosis(capsys):
    import json

    from benchmarks.null_rate import summarize

    runs = [{"plant": "bench", "train": "random", "naming": "named", "effects": [], "structure": []}] * 3
    failed = [{"plant": "bench", "seed": 7, "train": "closed_loop", "naming": "named",
               "error": "RuntimeError: rtlift control exited 1"}]
    summarize(runs, 5, 0.0, failed)
    lines = capsys.readouterr().out.strip().splitlines()
    out = json.loads(lines[-1])
    assert out["clean_runs"] == 3 and out["planned_runs"] == 5 and out["failed_runs"] == failed
    assert "1 planned runs not run, 1 failed" in "\n".join(lines)

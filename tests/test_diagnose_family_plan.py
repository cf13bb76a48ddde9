"""The family diagnosis benchmark's plan (benchmarks/diagnose_family.py): what it promises to run."""

from collections import Counter

from benchmarks.diagnose_family import FORMS, middle_size, plan
from benchmarks.power import SIZES


def test_the_plan_tries_every_effect_in_each_form_on_half_the_draws_and_the_null_reps_on_all():
    draws = list(range(100, 120))
    tasks = plan(draws, 5, None, "m")
    null = [t for t in tasks if t[0] == "null"]
    power = [t for t in tasks if t[0] == "power"]
    assert len(null) == 20 * 5 * 2
    assert Counter((t[1], t[3]) for t in null) == {(d, f): 5 for d in draws for f in FORMS}
    per_draw = Counter((t[1], t[4]) for t in power)
    assert per_draw == {(d, e): 1 for d in draws for e in SIZES}         # every effect once on every draw
    assert Counter((t[4], t[3]) for t in power) == {(e, f): 10 for e in SIZES for f in FORMS}
    seeds = [t[5] for t in tasks]
    assert len(set(seeds)) == len(seeds)                                # no two diagnoses share records


def test_a_run_stopped_early_is_balanced_over_draws():
    tasks = plan(list(range(100, 120)), 5, None, "m")
    first = tasks[:80]                                                  # the first repetition: every draw, both kinds
    assert {t[1] for t in first if t[0] == "null"} == set(range(100, 120))
    assert {t[1] for t in first if t[0] == "power"} == set(range(100, 120))


def test_the_middle_size_is_the_grids_middle():
    assert [middle_size(e) for e in ("delay", "sensor_resonance", "actuator_fade", "zero_drift",
                                     "periodic_disturbance", "hysteresis")] == [0.04, 0.05, 0.6, 8e-4, 0.01, 0.2]

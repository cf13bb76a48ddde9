"""Fault matrix, every fault at once over a long stream: the soak's seeded injector
(:mod:`testkit.wire_faults`, ``benchmarks/soak.py`` its command line) on half a minute of bench
frames, through the decoder, the converter and the observer loop. The full hour (memory) is
``python benchmarks/soak.py``."""

from __future__ import annotations

from testkit.wire_faults import RATES, soak


def _exact(r: dict) -> dict:
    """Every fault kind was injected; counters and the loop's checks are exact."""
    assert all(count > 0 for count in r["injected"].values()), r["injected"]
    assert r["counters"] == r["expected_counters"]
    assert r["checks"] == dict.fromkeys(r["checks"], True)
    return r


def test_mixed_faults_long_stream(record_property):
    """With every kind of fault sprinkled at ~30× the soak's rates, the decoder's counters
    equal what was injected and the observer's steps add up to the samples sent."""
    r = _exact(soak(0.5, seed=3, rates={k: 30 * v for k, v in RATES.items()}))
    record_property("measured", f"{r['samples']} samples, {r['faults_injected']} faults of {len(RATES)} kinds: "
                                f"counters == injected ({r['counters']}); observer steps add up")


def test_mixed_can_faults_long_stream(record_property):
    """The CAN soak's injector (three frames per sample: truncated, dropped, duplicated, late,
    reordered, error and foreign frames, flagged and absurd samples) at ~30× its rates: the
    assembler's counters equal what was injected and the observer's steps add up."""
    from testkit.wire_faults import CAN_RATES, can_soak

    r = _exact(can_soak(0.5, seed=4, rates={k: 30 * v for k, v in CAN_RATES.items()}))
    record_property("measured", f"CAN: {r['samples']} samples, {r['faults_injected']} faults of {len(CAN_RATES)} "
                                f"kinds: counters == injected ({r['counters']}); observer steps add up")

"""Fault matrix, every fault at once over a long stream: the soak benchmark's seeded injector
(``benchmarks/soak.py``) on half a minute of bench frames, through the decoder, the
converter and the observer loop. The full hour (memory) is ``python benchmarks/soak.py``."""

from __future__ import annotations

from benchmarks.soak import RATES, soak


def test_mixed_faults_long_stream(record_property):
    """With every kind of fault sprinkled at ~30× the soak's rates, the decoder's counters
    equal what was injected and the observer's steps add up to the samples sent."""
    r = soak(0.5, seed=3, rates={k: 30 * v for k, v in RATES.items()})
    assert all(count > 0 for count in r["injected"].values()), r["injected"]
    assert r["counters"] == r["expected_counters"]
    assert r["checks"] == dict.fromkeys(r["checks"], True)
    record_property("measured", f"{r['samples']} samples, {r['faults_injected']} faults of {len(RATES)} kinds: "
                                f"counters == injected ({r['counters']}); observer steps add up")

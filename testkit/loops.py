"""Checks the control-design tests share: a point's stated margins held against its loop."""

from __future__ import annotations

import math

import numpy as np
import pytest


def assert_crossovers_are_the_loop_s(point, dt: float) -> None:
    """At each gain crossover the point states, |L| = 1 (to 2e-3) and 180° − |∠L| is its phase
    margin (to 0.2°); at each phase crossover L is real and negative (|Im L| ≤ 2e-3 |L|) and
    20 log₁₀|L| is its gain (to 0.02 dB). L(z) is the point's own loop, z = exp(2πj f dt)."""
    L = point.loop(dt)
    m = point.margins
    for f, pm in m.gain_crossovers:
        v = L(np.exp(2j * np.pi * f * dt))
        assert abs(v) == pytest.approx(1.0, abs=2e-3)
        assert 180 - abs(math.degrees(np.angle(v))) == pytest.approx(pm, abs=0.2)
    for f, db in m.phase_crossovers:
        v = L(np.exp(2j * np.pi * f * dt))
        assert v.real < 0 and abs(v.imag) <= 2e-3 * abs(v)
        assert 20 * math.log10(abs(v)) == pytest.approx(db, abs=0.02)

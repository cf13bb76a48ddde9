"""Step-response scoring on the bench truth (rtlift.app.hil_tracking.settling_times) on signals
with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from rtlift.app.hil_tracking import settling_times
from rtlift.core.rate import FS_HZ

FS = int(FS_HZ)


def _first_order(reference: np.ndarray, tau_s: float) -> np.ndarray:
    a = np.exp(-1.0 / (tau_s * FS))
    y = np.empty_like(reference)
    acc = reference[0]
    for k, r in enumerate(reference):
        acc = a * acc + (1 - a) * r
        y[k] = acc
    return y


def test_a_first_order_response_settles_when_its_exponential_falls_below_the_tolerance():
    r = np.concatenate([np.full(2 * FS, 0.05), np.full(4 * FS, 0.15), np.full(4 * FS, 0.10)])
    y = _first_order(r, 0.3)
    got = settling_times(y, r, FS, tol=0.01, window=1)
    # |error| = A exp(-t/τ) < tol  ⇔  t > τ ln(A / tol): A = 0.1 then 0.05
    assert got == pytest.approx([0.3 * np.log(0.10 / 0.01), 0.3 * np.log(0.05 / 0.01)], abs=2.5 / FS)


def test_burst_ripple_is_averaged_out_and_an_unreachable_level_never_settles():
    r = np.concatenate([np.full(2 * FS, 0.05), np.full(3 * FS, 0.40), np.full(3 * FS, 0.12)])
    reach = np.minimum(r, 0.22)                                   # the actuator's reach
    y = _first_order(reach, 0.2) + 0.03 * np.sin(2 * np.pi * np.arange(r.size) / 50)
    settle, recover = settling_times(y, r, FS, tol=0.01, window=50)
    assert settle is None                                         # 0.40 is beyond reach
    # from 0.22 down to 0.12: 0.2 ln(0.10 / 0.01) = 0.46 s, plus at most one window of lag
    assert 0.2 * np.log(10) <= recover <= 0.2 * np.log(10) + 50 / FS
    unaveraged = settling_times(y, r, FS, tol=0.01, window=1)[1]   # the ripple (0.03) alone exceeds 0.01
    assert unaveraged is None or unaveraged > 2.5


def test_a_constant_reference_has_no_step_to_settle_after():
    r = np.full(4 * FS, 0.08)
    assert settling_times(_first_order(r, 0.2), r, FS) == []

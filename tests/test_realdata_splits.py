"""The Silverbox tests of the frozen protocol (``benchmarks/realdata.py``, issue 48): the official
multisine test (``silverbox_multisine``, the record the published DT SUBNET 0.36 mV is on) is the
last 25 % of the multisine section, after and apart from the estimation data every Silverbox
benchmark shares."""

from __future__ import annotations

import numpy as np

from rtlift.sysid import benchmarks as splits


def test_the_silverbox_multisine_test_is_the_official_last_quarter_after_the_estimation_data():
    d = np.load(splits.DATA_DIR / "silverbox_SNLS80mV.npz")
    fs, [(_, ue, ye)] = splits.estimation("silverbox_multisine")
    [(label, ut, yt)] = splits.tests("silverbox_multisine")
    assert fs == float(d["fs"]) and label == "test"
    assert (ue.size, ut.size) == (65062, 21688)              # 75 % / 25 % of data[40650:127400]
    np.testing.assert_array_equal(np.concatenate([ue, ut]), d["V1"][40650:127400])
    np.testing.assert_array_equal(np.concatenate([ye, yt]), d["V2"][40650:127400])
    for name in ("silverbox", "silverbox_schroeder"):         # one estimation set for the three tests
        np.testing.assert_array_equal(splits.estimation(name)[1][0][1], ue)

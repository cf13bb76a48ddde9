"""How a run is split for diagnosis (``rtlift diagnose --run``, ``--adapt``'s windows), defined once.

The effects are fitted on the run's first :data:`SPLIT_DEFAULT` and judged on the rest; each part
must be long enough for its job (:data:`MIN_TRAIN_S`, :data:`MIN_VALIDATE_S`). In the core, so the
command line's help (built before the diagnosis package and scipy load), the diagnosis itself
(:mod:`rtlift.diagnose.sources`) and the live loop's adapter (:mod:`rtlift.app.adapt`) read one number.
"""

from __future__ import annotations

SPLIT_DEFAULT = 0.6
"""``--run``: the share of the run the effects are fitted on. The fits carry the diagnosis (a
fade's time constant, a drift's course need the longer part); 40 % left is still ≥ 10 one-second
significance blocks on a run of 25 s, and ≥ 24 on a minute's run."""
MIN_TRAIN_S = 12.0
"""A lift training record's least length (s): 2 s from rest left out of the residual tests, 10 s tested."""
MIN_VALIDATE_S = 10.0
"""A lift run's validation part's least length (s): ten 1 s blocks for the significance test."""

"""The simulated bench: a truth plant that is *not* the hybrid model, its actuator and
sensor chains, injectable effects and the standard experiments (docs/BENCH.md).

``hil_sim.experiments.run_experiment`` gives one experiment as a :class:`BenchRun`;
``hil_sim.experiments.daq_stream`` streams one-second chunks forever for the device
emulators in ``hil_sim.devices``.
"""

from __future__ import annotations

from rtlift.core.rate import FS_HZ as FS_HZ  # the bench samples at the DAQ's rate

CHORD_M = 0.245
U_INF_M_S = 3.0
T_CONV_S = CHORD_M / U_INF_M_S
"""Convective time c/U∞ ≈ 0.0817 s (the paper's t_convect); t⁺ = t / T_CONV_S."""

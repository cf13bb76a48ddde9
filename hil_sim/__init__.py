"""The simulated bench: a truth plant that is *not* the hybrid model, its actuator and
sensor chains, injectable effects and the standard experiments (docs/BENCH.md).

``hil_sim.experiments.run_experiment`` gives one experiment as a :class:`BenchRun`;
``hil_sim.experiments.daq_stream`` streams one-second chunks forever for the device
emulators in ``hil_sim.devices``.
"""

from __future__ import annotations

from rtlift.core.programs import CHORD_M as CHORD_M  # the paper's wing and flow (t⁺ = t / T_CONV_S)
from rtlift.core.programs import T_CONV_S as T_CONV_S
from rtlift.core.programs import U_INF_M_S as U_INF_M_S
from rtlift.core.rate import FS_HZ as FS_HZ  # the bench samples at the DAQ's rate

"""The paper's wing, flow, actuators and transducer (An, Williams & Hemati; PROTOCOL.md), defined once.

Three users read them: the host's default :class:`firmware_io.calibration.Calibration` (the rig
it describes when a lab gives no calibration file), the simulated bench's
:class:`hil_sim.physics.BenchPhysics` (the truth it simulates, with its own conversion code) and
the experiment programs (:mod:`rtlift.core.programs`: t⁺ = t U∞ / c, Cμ ↔ volts). They sit in the
core so that every one of them may import them (``firmware_io`` and ``hil_sim`` import only the
core of rtlift: tests/test_layers.py).

Units SI; the actuators' law Cμ = κ V² with κ = Cμ(60 V) / (60 V)².
"""

from __future__ import annotations

CHORD_M = 0.245
"""Chord c (m)."""
SPAN_M = 0.596
"""Span b (m)."""
ALPHA_DEG = 20.0
"""Angle of attack α (degrees): the stalled wing."""
U_INF_M_S = 3.0
"""Free stream U∞ (m/s)."""
RHO_KG_M3 = 1.2
"""Air density ρ (kg/m³)."""
CMU_AT_60V = 0.0022
"""The paper's single-burst and burst-train amplitude: 60 V ↔ Cμ 0.0022."""
CMU_PER_VOLT2 = CMU_AT_60V / 60.0**2
"""κ in Cμ = κ V² (1/V²)."""
COUNTS_PER_N = 1.0e6
"""The serial transducer's counts per newton (PROTOCOL.md's default)."""
COUNTS_PER_NM = 1.0e9
"""The serial transducer's counts per newton-metre (PROTOCOL.md's default)."""

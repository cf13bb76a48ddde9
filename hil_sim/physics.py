"""The simulated rig's own physical constants: the wing in the tunnel, the actuators' law and the
transducer's scaling, as the bench's physics sees them.

The conversions are written here, apart from the host's :class:`firmware_io.calibration.Calibration`,
so that the truth of the bench does not borrow the host's conversion code (the paper's numbers, the
defaults of both, are :mod:`rtlift.core.wing`'s): a mistake in the host's calibration
code (a sign, an angle, a scale) shows in every record the host writes, instead of cancelling in
the round trip. The defaults are the paper's wing and PROTOCOL.md's transducer, the rig the host's
default calibration describes; :meth:`BenchPhysics.calibration` is the host calibration that
describes *this* rig (what a lab would measure and write in its calibration file).

Equations (SI units):

- the wing's force for ΔCL = 1: q_A = ½ ρ U∞² c b;
- the transducer's axes (x along the chord, z normal to it, mounting signs s_x, s_z):
  Fz = s_z q_A (CL cos α + CD sin α), Fx = s_x q_A (−CL sin α + CD cos α), Ty = q_A c CM;
- its firmware scaling: counts = F × counts per N (forces), T × counts per N·m (torques);
- the actuators: Cμ = κ V² with κ = 0.0022 / 60² (60 V ↔ Cμ 0.0022, the paper's actuators).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtlift.core import wing


@dataclass(frozen=True)
class BenchPhysics:
    """The simulated rig (module docstring): wing, tunnel, mounting, actuators, transducer scaling;
    the defaults are the paper's (:mod:`rtlift.core.wing`)."""

    chord_m: float = wing.CHORD_M
    span_m: float = wing.SPAN_M
    alpha_deg: float = wing.ALPHA_DEG
    u_inf_m_s: float = wing.U_INF_M_S
    rho_kg_m3: float = wing.RHO_KG_M3
    sign_fx: float = 1.0
    sign_fz: float = 1.0
    cmu_per_volt2: float = wing.CMU_PER_VOLT2
    counts_per_n: float = wing.COUNTS_PER_N
    counts_per_nm: float = wing.COUNTS_PER_NM

    @property
    def q_area(self) -> float:
        """½ ρ U∞² c b (N)."""
        return 0.5 * self.rho_kg_m3 * self.u_inf_m_s**2 * self.chord_m * self.span_m

    def cmu_from_volts(self, volts: np.ndarray) -> np.ndarray:
        """Cμ = κ V², what the actuators deliver at a drive amplitude."""
        v = np.asarray(volts, dtype=float)
        return self.cmu_per_volt2 * v * v

    def forces(self, coeffs: np.ndarray) -> np.ndarray:
        """(n, 3) CL CD CM → (n, 6) fx fy fz (N), tx ty tz (N·m) on the transducer's axes."""
        alpha = math.radians(self.alpha_deg)
        qa = self.q_area
        cl, cd, cm = coeffs[:, 0], coeffs[:, 1], coeffs[:, 2]
        ft = np.zeros((len(cl), 6))
        ft[:, 0] = self.sign_fx * qa * (-cl * math.sin(alpha) + cd * math.cos(alpha))
        ft[:, 2] = self.sign_fz * qa * (cl * math.cos(alpha) + cd * math.sin(alpha))
        ft[:, 4] = qa * self.chord_m * cm
        return ft

    def counts(self, ft: np.ndarray) -> np.ndarray:
        """SI forces/torques (..., 6) → counts (float; the caller rounds and saturates)."""
        ft = np.asarray(ft, dtype=float)
        return np.concatenate([ft[..., :3] * self.counts_per_n, ft[..., 3:] * self.counts_per_nm], axis=-1)

    def si(self, counts: np.ndarray) -> np.ndarray:
        """Counts (..., 6) → N and N·m (the firmware's own scaling, as the CAN frames carry them)."""
        c = np.asarray(counts, dtype=float)
        return np.concatenate([c[..., :3] / self.counts_per_n, c[..., 3:] / self.counts_per_nm], axis=-1)

    def calibration(self):
        """The host calibration that describes this rig exactly (a lab's measured calibration file)."""
        from firmware_io.calibration import Calibration

        return Calibration(counts_per_n=self.counts_per_n, counts_per_nm=self.counts_per_nm, chord_m=self.chord_m,
                           span_m=self.span_m, alpha_deg=self.alpha_deg, u_inf_m_s=self.u_inf_m_s,
                           rho_kg_m3=self.rho_kg_m3, sign_fx=self.sign_fx, sign_fz=self.sign_fz,
                           kappa=self.cmu_per_volt2)

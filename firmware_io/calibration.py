"""Calibration: firmware counts → SI forces → ΔCL, and drive voltage → Cμ (PROTOCOL.md).

Equations (SI units):

- transducer: ``FT = M · (counts / scale)``, ``scale`` = counts per N for fx fy fz and counts
  per N·m for tx ty tz, ``M`` an optional 6×6 matrix (identity by default);
- lift: ``L = s_z Fz cos α − s_x Fx sin α`` (transducer x along the chord, z normal to it;
  ``s_x``, ``s_z`` the sign conventions of the mounting), ``CL = L / (½ ρ U∞² c b)``;
- tare: ``ΔCL = CL − CL_tare`` (stored, or the mean of the first ``tare_seconds`` with the
  actuator off);
- actuator: ``Cμ = κ V²`` with κ such that 60 V ↔ Cμ 0.0022, or a lookup table (V, Cμ)
  from a hot-wire calibration.

A calibration file is TOML with any of the field names of :class:`Calibration` at top level,
for example ``alpha_deg = 20.0`` or ``cmu_table_v = [0, 30, 60]`` with ``cmu_table = [...]``;
:data:`EXAMPLE_PATH` (``firmware_io/calibration_example.toml``) has every key, commented.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace

import numpy as np

from rtlift.core import wing
from rtlift.core.errors import UserError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]


EXAMPLE_PATH = os.path.join(os.path.dirname(__file__), "calibration_example.toml")
"""The example calibration file shipped with the package: every key, commented, with units."""


class CalibrationError(UserError):
    """A calibration file that cannot be used."""


@dataclass(frozen=True)
class Calibration:
    """One bench's calibration; defaults are the paper's wing and PROTOCOL.md's transducer
    (:mod:`rtlift.core.wing`)."""

    counts_per_n: float = wing.COUNTS_PER_N
    counts_per_nm: float = wing.COUNTS_PER_NM
    matrix: tuple[tuple[float, ...], ...] | None = None
    chord_m: float = wing.CHORD_M
    span_m: float = wing.SPAN_M
    alpha_deg: float = wing.ALPHA_DEG
    u_inf_m_s: float = wing.U_INF_M_S
    rho_kg_m3: float = wing.RHO_KG_M3
    sign_fx: float = 1.0
    sign_fz: float = 1.0
    tare_cl: float | None = None
    tare_seconds: float = 2.0
    kappa: float = wing.CMU_PER_VOLT2
    cmu_table_v: tuple[float, ...] = field(default=())
    cmu_table: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise CalibrationError(f"calibration: {f.name} = {v} is not finite")
        for name in ("counts_per_n", "counts_per_nm", "chord_m", "span_m", "u_inf_m_s",
                     "rho_kg_m3", "kappa"):
            if getattr(self, name) <= 0:
                raise CalibrationError(f"calibration: {name} must be positive, got {getattr(self, name)}")
        if self.matrix is not None:
            m = np.asarray(self.matrix, dtype=float)
            if m.shape != (6, 6) or not np.all(np.isfinite(m)):
                raise CalibrationError(f"calibration: matrix must be 6x6 finite numbers, got shape {m.shape}")
        if len(self.cmu_table_v) != len(self.cmu_table):
            raise CalibrationError("calibration: cmu_table_v and cmu_table differ in length")
        if self.cmu_table_v and np.any(np.diff(self.cmu_table_v) <= 0):
            raise CalibrationError("calibration: cmu_table_v must be strictly increasing")

    # -- construction -------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike | None) -> Calibration:
        """Read a TOML calibration file (``None``: the defaults)."""
        if path is None:
            return cls()
        try:
            with open(path, "rb") as f:
                raw = tomllib.load(f)
        except FileNotFoundError:
            raise CalibrationError(f"{path}: no such calibration file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise CalibrationError(f"{path}: cannot read calibration file ({exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise CalibrationError(f"{path}: not valid TOML ({exc})") from None
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise CalibrationError(f"{path}: unknown calibration key '{unknown[0]}'")
        kwargs = {}
        for key, value in raw.items():
            if key == "matrix":
                value = tuple(tuple(float(x) for x in row) for row in value)
            elif key in ("cmu_table_v", "cmu_table"):
                value = tuple(float(x) for x in value)
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                value = float(value)
            else:
                raise CalibrationError(f"{path}: calibration key '{key}' must be a number")
            kwargs[key] = value
        try:
            return cls(**kwargs)
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {exc}") from None

    def with_tare(self, tare_cl: float) -> Calibration:
        return replace(self, tare_cl=float(tare_cl))

    # -- forward: what the host computes ------------------------------------------------
    @property
    def q_area(self) -> float:
        """½ ρ U∞² c b, the force that corresponds to ΔCL = 1 (N)."""
        return 0.5 * self.rho_kg_m3 * self.u_inf_m_s**2 * self.chord_m * self.span_m

    def si_from_counts(self, fx: int, fy: int, fz: int, tx: int, ty: int,
                       tz: int) -> tuple[float, float, float, float, float, float]:
        """One sample's six transducer counts → fx fy fz (N) = counts / ``counts_per_n``, tx ty
        tz (N·m) = counts / ``counts_per_nm``; no matrix (:class:`firmware_io.convert.Converter`
        applies it). What the serial decoder delivers as ``Sample.ft``; scalar arithmetic, the
        same operations as :meth:`ft_from_counts` before its matrix."""
        cpn = self.counts_per_n
        cpnm = self.counts_per_nm
        return (fx / cpn, fy / cpn, fz / cpn, tx / cpnm, ty / cpnm, tz / cpnm)

    def ft_from_counts(self, counts: np.ndarray) -> np.ndarray:
        """Six transducer counts (..., 6) → fx fy fz (N), tx ty tz (N·m), matrix applied
        (:meth:`si_from_counts` over arrays, then ``M``)."""
        c = np.asarray(counts, dtype=float)
        ft = np.concatenate([c[..., :3] / self.counts_per_n, c[..., 3:] / self.counts_per_nm], axis=-1)
        if self.matrix is not None:
            ft = ft @ np.asarray(self.matrix, dtype=float).T
        return ft

    def cl_from_ft(self, ft: np.ndarray) -> np.ndarray | float:
        """CL = (s_z Fz cos α − s_x Fx sin α) / (½ ρ U∞² c b), not tared."""
        a = math.radians(self.alpha_deg)
        ft = np.asarray(ft, dtype=float)
        lift = self.sign_fz * ft[..., 2] * math.cos(a) - self.sign_fx * ft[..., 0] * math.sin(a)
        return lift / self.q_area

    def cmu_from_volts(self, volts: np.ndarray | float) -> np.ndarray | float:
        """Cμ = κ V² (or the hot-wire table, linear between its points, clamped at its ends)."""
        v = np.abs(np.asarray(volts, dtype=float))
        if self.cmu_table_v:
            out = np.interp(v, self.cmu_table_v, self.cmu_table)
        else:
            out = self.kappa * v * v
        return float(out) if out.ndim == 0 else out

    def tare_from(self, cl: np.ndarray, volts: np.ndarray, fs_hz: float) -> float:
        """Mean CL over the first ``tare_seconds`` of samples with the actuator off."""
        n = max(1, int(round(self.tare_seconds * fs_hz)))
        off = np.asarray(cl)[:n][np.asarray(volts)[:n] == 0]
        if off.size == 0:
            raise CalibrationError("cannot tare: the actuator is never off in the first "
                                   f"{self.tare_seconds} s (store tare_cl in the calibration)")
        return float(np.mean(off))

    # -- inverse: what the simulated bench needs ----------------------------------------
    def volts_from_cmu(self, cmu: np.ndarray | float) -> np.ndarray | float:
        """The drive amplitude that gives ``cmu`` (inverse of :meth:`cmu_from_volts`)."""
        c = np.maximum(np.asarray(cmu, dtype=float), 0.0)
        if self.cmu_table_v:
            out = np.interp(c, self.cmu_table, self.cmu_table_v)
        else:
            out = np.sqrt(c / self.kappa)
        return float(out) if out.ndim == 0 else out

    def counts_from_ft(self, ft: np.ndarray) -> np.ndarray:
        """SI forces/torques (..., 6) → counts (float; the caller rounds and saturates)."""
        ft = np.asarray(ft, dtype=float)
        if self.matrix is not None:
            ft = ft @ np.linalg.inv(np.asarray(self.matrix, dtype=float)).T
        return np.concatenate([ft[..., :3] * self.counts_per_n, ft[..., 3:] * self.counts_per_nm], axis=-1)

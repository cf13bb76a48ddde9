"""The observer's settings: noise variances Q and R, the χ² gate, the extra state blocks asked
for (the model file's ``observer`` section), and the flags an :class:`~rtlift.observer.Estimate`
carries.

Names follow the equations of :mod:`rtlift.observer` (Simon, *Optimal State Estimation*,
ch. 5 and 13; Bar-Shalom et al., *Estimation with Applications to Tracking*, ch. 5: NIS and
the χ² gate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import ndtri

from rtlift.core.errors import UserError

FLAG_MISSING = 1
"""No measurement (missing or flagged sample): predict only."""
FLAG_REJECTED = 2
"""Innovation outside the χ² gate: measurement rejected, predict only."""
FLAG_GATE_RELEASED = 4
"""Outside the gate but accepted: ``max_rejections`` outliers have piled up (module docstring)."""
FLAG_BAD_INPUT = 8
"""Cμ or Cμ_env was NaN/±inf: the last finite inputs are held and the sample is predict-only."""
GATE_LEAK = 0.25
"""What a sample inside the gate takes off the outlier count: the gate opens when more than
one sample in five falls outside it for a while (a consistent filter: one in 10⁴)."""

CONFIG_VERSION = 1


def chi2_1_quantile(p: float) -> float:
    """Quantile of χ² with one degree of freedom: ``(Φ⁻¹((1 + p)/2))²``."""
    return math.inf if p >= 1.0 else float(ndtri(0.5 * (1.0 + p))) ** 2


NIS_BAND = (chi2_1_quantile(0.025), chi2_1_quantile(0.975))
"""Central 95 % interval of χ²₁: a consistent filter has 95 % of its NIS values inside."""


class ObserverError(UserError):
    """A model that cannot be observed (no observer settings, an unsupported stage)."""


@dataclass(frozen=True)
class ObserverConfig:
    """Noise settings (the model file's ``observer`` section)."""

    R: float                        # measurement noise variance (ΔCL²)
    q_x: float                      # Wiener disturbance variance per sample (y²)
    q_bias: float                   # bias random-walk variance per sample (ΔCL²)
    p0_bias: float                  # initial bias variance (ΔCL²)
    gate_probability: float = 0.9999
    max_rejections: int = 40
    noise_ar: tuple[float, ...] = ()  # AR coefficients of a coloured part of the noise (() : white only)
    q_noise: float = 0.0            # its driving variance per sample (ΔCL²)
    q_gain_h: float = 0.0           # random-walk variance of a relative gain error of ΔCL_H (0: none)
    ripple_harmonics: int = 0       # H burst-synchronous harmonics (0: no ripple states)
    ripple_powers: int = 1          # amplitude terms Cμ_env (Cμ_env/Cμ_ref)^(p−1), p = 1 … ripple_powers
    q_ripple: float = 0.0           # ripple coefficient random-walk variance per sample (ΔCL²/Cμ²)
    p0_ripple: float = 0.0          # initial ripple coefficient variance (ΔCL²/Cμ²)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise_ar", tuple(float(a) for a in self.noise_ar))
        for name in ("R", "q_x", "q_bias", "p0_bias", "q_ripple", "p0_ripple", "q_noise", "q_gain_h"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ObserverError(f"observer setting {name} must be a finite number >= 0, got {v!r}")
        if self.R <= 0:
            raise ObserverError(f"observer setting R must be positive, got {self.R!r}")
        if not 0.5 < self.gate_probability <= 1.0:
            raise ObserverError(f"observer gate_probability must be in (0.5, 1], got {self.gate_probability!r}")
        if len(self.noise_ar) > 8 or not all(math.isfinite(a) for a in self.noise_ar) or (
                self.noise_ar and max(abs(np.roots([1.0, *(-a for a in self.noise_ar)]))) >= 1.0):
            raise ObserverError(f"observer noise_ar must be the coefficients of a stable AR model "
                                f"(at most 8), got {list(self.noise_ar)!r}")
        if not (isinstance(self.ripple_powers, int) and 1 <= self.ripple_powers <= 4):
            raise ObserverError(f"observer ripple_powers must be an integer in [1, 4], got {self.ripple_powers!r}")
        if not (isinstance(self.ripple_harmonics, int) and 0 <= self.ripple_harmonics <= MAX_HARMONICS):
            raise ObserverError(f"observer ripple_harmonics must be an integer in [0, {MAX_HARMONICS}], "
                                f"got {self.ripple_harmonics!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "model") -> ObserverConfig:
        if not d or "R" not in d:
            raise ObserverError(f"{source}: the model file has no observer settings (Q and R); "
                                "run rtlift.observer.tune_observer on recorded data and save them "
                                "with save_model(..., observer=...)")
        try:
            harmonics = d.get("ripple_harmonics", 0)
            if isinstance(harmonics, float) and harmonics.is_integer():
                harmonics = int(harmonics)
            return cls(R=float(d["R"]), q_x=float(d["q_x"]), q_bias=float(d["q_bias"]),
                       p0_bias=float(d.get("p0_bias", d["R"])),
                       gate_probability=float(d.get("gate_probability", 0.9999)),
                       max_rejections=int(d.get("max_rejections", 40)),
                       noise_ar=tuple(float(a) for a in d.get("noise_ar", ())),
                       q_noise=float(d.get("q_noise", 0.0)),
                       q_gain_h=float(d.get("q_gain_h", 0.0)),
                       ripple_harmonics=harmonics,
                       ripple_powers=int(d.get("ripple_powers", 1)),
                       q_ripple=float(d.get("q_ripple", 0.0)),
                       p0_ripple=float(d.get("p0_ripple", 0.0)),
                       extra={k: v for k, v in d.items() if k not in _CONFIG_KEYS})
        except (KeyError, TypeError, ValueError) as exc:
            raise ObserverError(f"{source}: bad observer settings ({exc})") from None

    def to_dict(self) -> dict[str, Any]:
        return {"version": CONFIG_VERSION, "R": self.R, "q_x": self.q_x, "q_bias": self.q_bias,
                "p0_bias": self.p0_bias, "gate_probability": self.gate_probability,
                "max_rejections": self.max_rejections, "noise_ar": list(self.noise_ar),
                "q_noise": self.q_noise, "ripple_harmonics": self.ripple_harmonics,
                "ripple_powers": self.ripple_powers, "q_gain_h": self.q_gain_h,
                "q_ripple": self.q_ripple, "p0_ripple": self.p0_ripple, **self.extra}


MAX_HARMONICS = 16
_CONFIG_KEYS = {"R", "q_x", "q_bias", "p0_bias", "gate_probability", "max_rejections",
                "noise_ar", "q_noise", "q_gain_h", "ripple_harmonics", "ripple_powers", "q_ripple",
                "p0_ripple"}


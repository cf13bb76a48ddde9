"""The effect catalog: one :class:`Effect` record per lift effect of the registry
(:mod:`rtlift.core.registry`, which names each effect's fit, in :mod:`rtlift.diagnose.fits`, and
its evidence, here).

An effect's record holds its fit, the evidence that points at it (a statistic of the residual
compared with the model's own residual at identification, :mod:`rtlift.residual.fingerprint`), its
number of parameters and the effects it excludes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rtlift.core.effects import EffectSchema
from rtlift.core.records import Record
from rtlift.core.registry import EFFECTS as REGISTERED
from rtlift.core.registry import SCHEMAS, Entry, in_signal_order, resolve
from rtlift.diagnose.surgery import Context, Fitted, augment, predict, reestimate, rescaled
from rtlift.model.hybrid import HybridModel
from rtlift.residual.fingerprint import Departure, coef_departure, lag_departure, level_departure, psd_departure
from rtlift.residual.stats import TestResult

__all__ = ["CATALOG", "EFFECTS", "EFFECT_NAMES", "Context", "Effect", "Fitted", "augment", "predict", "reestimate",
           "rescaled"]


# ------------------------------------------------------------------ evidence against the print
def _no_print(what: str) -> Departure:
    return Departure(float("inf"), True, f"{what} (no fingerprint: compared with a white residual)")


def evidence_delay(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    d = int(round(fitted.params["seconds"] * fitted.model.fs_hz))
    return lag_departure(tests["lag"], fp, d) if fp else _no_print(f"lag {d} samples")


def evidence_resonance(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    f, z = fitted.params["frequency_hz"], fitted.params["damping_ratio"]
    df = float(tests["spectrum"].data["f"][1])
    half = max(2 * z * f, 2 * df)
    return psd_departure(tests["spectrum"], fp, [(f - half, f + half)], f"residual power near {f:.1f} Hz") \
        if fp else _no_print(f"mode at {f:.1f} Hz")


def evidence_fade(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    return coef_departure(tests["gain_trend"], fp, "gain drift", "/s") if fp else \
        _no_print(tests["gain_trend"].detail)


def evidence_drift(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    return coef_departure(tests["slow_trend"], fp, "offset drift", "/s") if fp else \
        _no_print(tests["slow_trend"].detail)


def evidence_pickup(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    f = fitted.params["frequency_hz"]
    df = float(tests["spectrum"].data["f"][1])
    return psd_departure(tests["spectrum"], fp, [(f - 1.5 * df, f + 1.5 * df)], f"line at {f:.2f} Hz") \
        if fp else _no_print(f"line at {f:.2f} Hz")


def evidence_hysteresis(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    return coef_departure(tests["direction"], fp, "falling-Cmu gain difference") if fp else \
        _no_print(tests["direction"].detail)


def evidence_output_nonlinearity(tests: dict[str, TestResult], fp: dict | None, fitted: Fitted) -> Departure:
    return level_departure(tests["level"], fp) if fp else _no_print(tests["level"].detail)


# ------------------------------------------------------------------ the catalog
@dataclass(frozen=True)
class Effect:
    """One effect: its shared schema (:data:`rtlift.core.effects.SCHEMAS`: meaning, parameters and
    their documented ranges), how it is fitted, what in the residual points at it, how many
    parameters it spends (from its fitted parameters) and which effects it cannot join."""

    name: str
    fit: Callable[[HybridModel, Record, Context], Fitted | str]
    evidence: Callable[[dict[str, TestResult], dict | None, Fitted], Departure]
    n_params: Callable[[dict[str, Any]], int]
    excludes: tuple[str, ...] = ()
    fits_change: bool = False
    """Replaces the model's static map: fitted to what changed since identification where the
    model's own misfit on the training input is known (:func:`.fingerprint.change_misfit`: the
    identification run it repeats, or the misfit predicted for its input), since that misfit is a
    misfit of the map too and a fit to the raw residual takes it for part of the effect."""
    bands: Callable[[dict[str, Any], float], list[tuple[float, float]]] | None = None
    """The frequency bands (Hz) an accepted fit accounts for, given its parameters and half a
    spectrum bin's width (:func:`rtlift.diagnose.unexplained.explained_bands`); ``None``: none."""

    @property
    def schema(self) -> EffectSchema:
        return SCHEMAS[self.name]


def n_params_drift(params: dict[str, Any]) -> int:
    """offset and rate, or offset, amplitude and time constant."""
    return 2 if "rate_per_s" in params else 3


def n_params_pickup(params: dict[str, Any]) -> int:
    """frequency, amplitude and phase of the fundamental, amplitude and phase per harmonic."""
    return 3 + 2 * len(params.get("harmonics", ()))


def bands_resonance(params: dict[str, Any], df: float) -> list[tuple[float, float]]:
    """A sensor mode's half-power band f(1 ± ζ), widened by half a spectrum bin ``df``."""
    f0, zeta = float(params["frequency_hz"]), float(params["damping_ratio"])
    return [(f0 * (1 - zeta) - 0.5 * df, f0 * (1 + zeta) + 0.5 * df)]


def bands_pickup(params: dict[str, Any], df: float) -> list[tuple[float, float]]:
    """A pickup's lines (the fundamental and its harmonics as sampled) ± 1.5 bins (the window its
    fit searches), widened by half a bin ``df``."""
    lines = [params["frequency_hz"], *(h["frequency_hz"] for h in params.get("harmonics", ()))]
    return [(float(x) - 2.0 * df, float(x) + 2.0 * df) for x in lines]


def _effect(entry: Entry) -> Effect:
    d = entry.diagnosis
    count = d.n_params
    n_params = resolve(count) if isinstance(count, str) else (lambda params: count)
    return Effect(entry.name, resolve(d.fit), resolve(d.evidence), n_params, d.excludes, d.fits_change,
                  resolve(d.bands) if d.bands else None)


CATALOG: tuple[Effect, ...] = tuple(_effect(e) for e in in_signal_order(REGISTERED))
"""The registry's lift effects (:mod:`rtlift.core.registry`) in the order a combination is built:
the signal path's (time and gain at the input, the nonlinearity, filter, additive)."""
EFFECTS: dict[str, Effect] = {e.name: e for e in CATALOG}
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)

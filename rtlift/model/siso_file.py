"""The single-input models' file form (:mod:`rtlift.model.siso`): JSON with ``"format":
"rtlift-siso-model"``, ``"version"``, ``"kind": "siso"`` and the ``"structure"`` whose model class
(:data:`rtlift.model.siso.MODEL_CLASSES`) reads the rest with its ``from_dict`` and writes it with
its ``to_dict``; a limit as ``"saturation": {"lower", "upper", "where"}``, infinite limits as
``null``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from rtlift.core.errors import ModelFileError
from rtlift.core.jsonfile import write_json_atomic

if TYPE_CHECKING:
    from rtlift.model.siso import FeedbackModel, SaturatedModel, SisoModel

FORMAT = "rtlift-siso-model"
VERSION = 1


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def model_from_dict(d: dict[str, Any], source: str = "model") -> SisoModel | FeedbackModel | SaturatedModel:
    """Build and check a model from its file form; :class:`ModelFileError` (one line) if wrong."""
    # the models import this module, so it imports them when called (tests/test_layers.py, LAZY_CYCLES)
    from rtlift.model.siso import LIMITED, MODEL_CLASSES, SaturatedModel, SisoModel, listed

    if d.get("format") != FORMAT or d.get("version") != VERSION:
        raise ModelFileError(f"{source}: not an rtlift single-input model file of version {VERSION}")
    sat = d.get("saturation")
    where = sat.get("where", "output") if isinstance(sat, dict) else None
    if sat is not None and where != "state":
        inner = model_from_dict({k: v for k, v in d.items() if k != "saturation"}, source)
        try:
            if where != "output":
                raise ValueError(f"saturation where {where!r} is not built (output, or state of "
                                 f"{listed(LIMITED['state'])})")
            return SaturatedModel(inner, *_limit_pair(sat))
        except (AttributeError, TypeError, ValueError) as exc:
            raise ModelFileError(f"{source}: {exc}") from None
    structure = d.get("structure")
    if where == "state" and structure not in LIMITED["state"]:
        raise ModelFileError(f"{source}: saturation where 'state' is built for {listed(LIMITED['state'])} only")
    cls = MODEL_CLASSES.get(structure, SisoModel) if isinstance(structure, str) else SisoModel
    try:
        return cls.from_dict(d)
    except KeyError as exc:
        raise ModelFileError(f"{source}: missing key {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{source}: {exc}") from None


def _limit_pair(sat: dict[str, Any]) -> tuple[float, float]:
    lo, hi = sat.get("lower"), sat.get("upper")
    return -np.inf if lo is None else float(lo), np.inf if hi is None else float(hi)


def save_siso_model(model: SisoModel | FeedbackModel | SaturatedModel, path: str | os.PathLike) -> None:
    write_json_atomic(path, model.to_dict(), stage="model file")

"""The single-input models' file form (:mod:`rtlift.model.siso`): JSON with ``"format":
"rtlift-siso-model"``, ``"version"``, ``"kind": "siso"`` and the ``"structure"`` whose model class
(:data:`rtlift.model.siso.MODEL_CLASSES`) reads the rest with its ``from_dict`` and writes it with
its ``to_dict`` (the models and their file form live in :mod:`rtlift.model.siso`, which imports
nothing of this module: a model copies itself without it); a limit as
``"saturation": {"lower", "upper", "where"}``, infinite limits as ``null``.
"""

from __future__ import annotations

import os
from typing import Any

from rtlift.core.errors import ModelFileError
from rtlift.core.jsonfile import write_json_atomic
from rtlift.model.siso import (
    FORMAT,
    LIMITED,
    MODEL_CLASSES,
    VERSION,
    FeedbackModel,
    SaturatedModel,
    SisoModel,
    StoreChainModel,
    _limit_pair,
    listed,
)

__all__ = ["FORMAT", "VERSION", "model_from_dict", "save_siso_model"]


def model_from_dict(d: dict[str, Any], source: str = "model"
                    ) -> SisoModel | FeedbackModel | StoreChainModel | SaturatedModel:
    """Build and check a model from its file form; :class:`ModelFileError` (one line) if wrong."""
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


def save_siso_model(model: SisoModel | FeedbackModel | StoreChainModel | SaturatedModel,
                    path: str | os.PathLike) -> None:
    """The model's file form (its ``to_dict``) written whole or not at all."""
    write_json_atomic(path, model.to_dict(), stage="model file")

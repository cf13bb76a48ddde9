"""The generic ``t,u,y`` model structures ``rtlift identify --record`` identifies, and where a
limit can sit in them (the effects and the diagnosis's structures are classes of their own, one
module each: :mod:`rtlift.effects`).

The model classes are named ``"module:attribute"`` and resolved by the model layer itself
(:data:`rtlift.model.siso.MODEL_CLASSES`, the only caller of :func:`resolve`).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ModelStructure:
    """A generic ``t,u,y`` model structure ``rtlift identify --record`` identifies."""

    name: str
    doc: str
    model: str


MODEL_STRUCTURES: tuple[ModelStructure, ...] = (     # the first is the default
    ModelStructure("wiener", "an LTI then a static map", "rtlift.model.siso:SisoModel"),
    ModelStructure("wiener_hammerstein", "a second LTI after the map", "rtlift.model.siso:SisoModel"),
    ModelStructure("nonlinear_feedback", "the output fed back through a cubic map into the LTI's input",
                   "rtlift.model.siso:FeedbackModel"),
    ModelStructure("store_chain", "two stores in cascade, each draining through a power-law outflow, "
                   "like two tanks", "rtlift.model.siso:StoreChainModel"),
)

LIMIT_FORMS: tuple[tuple[str, str], ...] = (
    ("wiener", "output"), ("wiener_hammerstein", "output"), ("nonlinear_feedback", "output"),
    ("nonlinear_feedback", "state"), ("store_chain", "state"))
"""The model structures a limit is built in, each with where it sits (the output, or a feedback
form's state: one store, or two in cascade): what identification takes and the generic
diagnosis's saturation structure tries (:mod:`rtlift.effects.saturation`)."""
MODEL_STRUCTURE_NAMES: tuple[str, ...] = tuple(s.name for s in MODEL_STRUCTURES)


def resolve(path: str) -> Any:
    """The object ``"module:attribute"`` names (imports the module: call it from the layer the
    module belongs to or above)."""
    mod, _, attr = path.partition(":")
    return getattr(importlib.import_module(mod), attr)

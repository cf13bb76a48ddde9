"""The generic ``t,u,y`` model structures ``rtlift identify --record`` identifies, and where a
limit can sit in them (the effects and the diagnosis's structures are classes of their own, one
module each: :mod:`rtlift.effects`).

Each structure's model class is the model layer's own (:data:`rtlift.model.siso.MODEL_CLASSES`,
from the classes' ``structure``): the core names nothing above it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ModelStructure:
    """A generic ``t,u,y`` model structure ``rtlift identify --record`` identifies."""

    name: str
    doc: str


MODEL_STRUCTURES: tuple[ModelStructure, ...] = (     # the first is the default
    ModelStructure("wiener", "an LTI then a static map"),
    ModelStructure("wiener_hammerstein", "a second LTI after the map"),
    ModelStructure("nonlinear_feedback", "the output fed back through a cubic map into the LTI's input"),
    ModelStructure("store_chain", "two stores in cascade, each draining through a power-law outflow, "
                   "like two tanks"),
)

LIMIT_FORMS: tuple[tuple[str, str], ...] = (
    ("wiener", "output"), ("wiener_hammerstein", "output"), ("nonlinear_feedback", "output"),
    ("nonlinear_feedback", "state"), ("store_chain", "state"))
"""The model structures a limit is built in, each with where it sits (the output, or a feedback
form's state: one store, or two in cascade): what identification takes and the generic
diagnosis's saturation structure tries (:mod:`rtlift.effects.saturation`)."""
MODEL_STRUCTURE_NAMES: tuple[str, ...] = tuple(s.name for s in MODEL_STRUCTURES)


"""The generic ``t,u,y`` model structures ``rtlift identify --record`` identifies, and where a
limit can sit in them (the effects and the diagnosis's structures are classes of their own, one
module each: :mod:`rtlift.effects`).

Each structure's model class is the model layer's own (:data:`rtlift.model.siso.MODEL_CLASSES`,
from the classes' ``structure``): the core names nothing above it.

And the one way a lower floor reaches what an upper floor defines: *stage providers*. A model
file names its stages; their classes register themselves by name when defined
(:data:`rtlift.blocks.stage_base.STAGES`), the model layer's own in :mod:`rtlift.blocks`, an
effect's own in its module of :mod:`rtlift.effects` (a floor above the model layer, which reads
model files). The package's entry (``rtlift/__init__.py``) hands down a callable that imports the
effects (:func:`add_stage_provider`); the stage lookup runs it (:func:`run_stage_providers`) only
for a name it does not know, so reading a model file of known stages imports nothing more.
Dependency injection: no floor imports one above it, by statement or by string
(``tests/test_layers.py``).
"""

from __future__ import annotations

from collections.abc import Callable
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



_STAGE_PROVIDERS: list[Callable[[], object]] = []


def add_stage_provider(provider: Callable[[], object]) -> None:
    """Register ``provider``: a callable that defines (imports) stage classes an upper floor
    owns; run at most once, by :func:`run_stage_providers` (module docstring)."""
    if provider not in _STAGE_PROVIDERS:
        _STAGE_PROVIDERS.append(provider)


def run_stage_providers() -> int:
    """Run every provider not run yet, in the order registered (each once); the number run."""
    ran = 0
    while _STAGE_PROVIDERS:
        _STAGE_PROVIDERS.pop(0)()
        ran += 1
    return ran

"""The ``saturation`` structure: a hard limit on the input, a state or the output, tried by the
generic diagnosis (:mod:`rtlift.sysid.diagnose`) where the measured output piles up at a level
(:func:`rtlift.sysid.diagnose.clip_levels`), in every model structure that takes a limit
(:data:`rtlift.core.registry.LIMIT_FORMS`, which identification checks too)."""

from __future__ import annotations

from rtlift.core.registry import LIMIT_FORMS
from rtlift.effects.base import Structure


class Saturation(Structure):
    name = "saturation"
    row = 30
    meaning = "a hard limit on the input, a state or the output (overflow, clipping, actuator limits)"
    how = ("the output (or a feedback form's state: one store, or two in cascade) clipped at the level the "
           "measurement piles up at, the model re-identified jointly with the limit in place (censored "
           "samples for an output limit) in each form")
    forms = LIMIT_FORMS

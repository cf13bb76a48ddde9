"""rtlift: a real-time hybrid Wiener–convolution lift model and observer for burst-actuated flow control.

The top-level names are imported on first use (PEP 562), so that ``import rtlift.core.errors``
(what ``firmware_io`` and ``hil_sim`` do) does not load the model, scipy or the observer.

It hands the effects' own stages down to the model file's reader (:mod:`rtlift.core.registry`'s
stage providers): :func:`_effect_stages` runs only when a model file names a stage the model layer
does not define.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from rtlift.core.registry import add_stage_provider

_EXPORTS = {"HybridModel": "rtlift.model.hybrid", "HybridOutput": "rtlift.model.hybrid",
            "load_model": "rtlift.model.modelfile", "save_model": "rtlift.model.modelfile",
            "Observer": "rtlift.observer"}

__all__ = ["HybridModel", "HybridOutput", "Observer", "load_model", "save_model"]


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'rtlift' has no attribute {name!r}")
    return getattr(import_module(_EXPORTS[name]), name)


def _effect_stages() -> None:
    """Import :mod:`rtlift.effects`: a stage an effect defines in its own module registers itself."""
    import_module("rtlift.effects")


add_stage_provider(_effect_stages)

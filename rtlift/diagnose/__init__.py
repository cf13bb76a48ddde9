"""Residual analysis and augmentation: find what the model misses, add it, report before/after.

- :mod:`.residual` — residual tests (whiteness, input and higher-order correlations, spectrum
  peaks, level/direction dependence, slow trend, lag search);
- :mod:`.fingerprint` — the model's own residual at identification, and how far a new
  record's residual departs from it (an effect) or not (structure);
- :mod:`.catalog` — one :class:`~.catalog.Effect` record per INTERFACES.md effect;
- :mod:`.selection` — combinations compared on held-out records, every member earning its place;
- :mod:`.report` — report.json, report.md, figures and the augmented model file.
"""

from rtlift.diagnose.catalog import EFFECT_NAMES
from rtlift.diagnose.selection import DiagnoseOptions, Diagnosis, diagnose

__all__ = ["EFFECT_NAMES", "DiagnoseOptions", "Diagnosis", "diagnose"]

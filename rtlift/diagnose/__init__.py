"""Residual analysis and augmentation: find what the model misses, add it, report before/after.

- :mod:`.residual` — residual tests (whiteness, input and higher-order correlations, spectrum
  peaks, level/direction dependence, slow trend, lag search);
- :mod:`.catalog` — one augmentation per effect of INTERFACES.md, each with its own fit;
- :mod:`.selection` — greedy forward selection judged on held-out records;
- :mod:`.report` — report.json, report.md, figures and the augmented model file.
"""

from rtlift.diagnose.catalog import EFFECT_NAMES
from rtlift.diagnose.selection import DiagnoseOptions, Diagnosis, diagnose

__all__ = ["EFFECT_NAMES", "DiagnoseOptions", "Diagnosis", "diagnose"]

"""Residual analysis and augmentation: find what the model misses, add it, report before/after.

(The residual tests and the model's own residual at identification, its fingerprint, live in
:mod:`rtlift.residual`, below identification, which stores the fingerprint in the model file.)

- the effects it tries are :mod:`rtlift.effects` (one module per INTERFACES.md effect);
- :mod:`.selection` — the one selection engine, for every model kind: candidates alone, a pool,
  combinations compared on held-out records, every member earning its place, the choice and the
  report; a kind offers its candidates through :class:`.selection.Candidates`;
- :mod:`.lift` — a lift model's candidates, the effects (:func:`diagnose`); a generic model's are
  :mod:`rtlift.sysid.diagnose`'s structures;
- :mod:`.significance` — the test a member passes on the held-out records, the table of combinations;
- :mod:`.unexplained` — what the diagnosis leaves unexplained, the report's ``unexplained`` lines;
- :mod:`.diagnosis` — the options, one entry's outcome and the diagnosis as the report writes it;
- :mod:`.report` — report.json, report.md, figures and the augmented model file, for a lift
  model's diagnosis and a generic ``t,u,y`` model's (:mod:`rtlift.sysid.diagnose`) alike;
- :mod:`.sources` — the records a diagnosis is given, or one long run split in two (``--run``).
"""

from rtlift.diagnose.diagnosis import DiagnoseOptions, Diagnosis
from rtlift.diagnose.lift import diagnose
from rtlift.effects import EFFECT_NAMES

__all__ = ["EFFECT_NAMES", "DiagnoseOptions", "Diagnosis", "diagnose"]

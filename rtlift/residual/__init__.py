"""The model's own residual, below both identification and diagnosis (which both use it):

- :mod:`.stats` — residual tests (whiteness, input and higher-order correlations, spectrum
  peaks, level/direction dependence, slow trend, lag search);
- :mod:`.fingerprint` — the model's residual at identification (stored in the model file), and
  how far a new record's residual departs from it (an effect) or not (structure);
- :mod:`.inputs` — what an input record is like (burst periods, envelope band), to find the
  campaign record nearest a new one;
- :mod:`.misfit` — the model's own misfit predicted for a new input.
"""

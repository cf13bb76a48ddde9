"""The model layer: the hybrid model (eq. 11) assembled from :mod:`rtlift.blocks`, its file,
its domain and the open-loop prediction every score uses.

- :mod:`.hybrid` — :class:`~rtlift.model.hybrid.HybridModel`: input stages, ring-buffer
  convolution, high-pass filter, Wiener block, output stages; ``step`` and its batch twin;
- :mod:`.modelfile` — the versioned JSON model file (checks shapes, finite values, stability);
- :mod:`.domain` — the burst periods and Cμ range a model was identified on;
- :mod:`.validation` — the prediction and the scores ``rtlift validate`` prints.

Imports :mod:`rtlift.core` and :mod:`rtlift.blocks` only (``tests/test_layers.py``).
"""

"""The core layer: what every other layer may import, and which imports nothing else of ours.

- :mod:`rtlift.core.errors`  the exceptions a user can act on (exit status 2);
- :mod:`rtlift.core.records` the record file (CSV with ``# key: value`` metadata) and :class:`Record`;
- :mod:`rtlift.core.metrics` ρ, NRMSE, RMSE;
- :mod:`rtlift.core.effects` one parameter schema per effect (shared by the model and the bench);
- :mod:`rtlift.core.rate`    the 400 Hz sample rate;
- :mod:`rtlift.core.programs` experiment programs (time, envelope, burst period) for the rig and the bench;
- :mod:`rtlift.core.wing`    the paper's wing, flow, actuators and transducer (calibration and bench defaults);
- :mod:`rtlift.core.split`   how a run is split for diagnosis (the share fitted on, the least parts);
- :mod:`rtlift.core.registry` the generic model structures (the effects: :mod:`rtlift.effects`), and the
  stage providers through which an upper floor hands its stages down to the model file's reader;
- :mod:`rtlift.core.jsonfile` JSON files written whole or not at all;
- :mod:`rtlift.core.textfile` a text file read whole, each failure one line;
- :mod:`rtlift.core.jit`     numba functions compiled with a cache safe across processes;
- :mod:`rtlift.core.threads` one BLAS thread for identification and diagnosis.

``firmware_io`` and ``hil_sim`` depend on this layer only (and on each other's codecs), never on
the model, the observer or the applications above it (``tests/test_layers.py`` checks it).
"""

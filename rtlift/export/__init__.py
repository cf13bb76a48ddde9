"""The model and its observer for use outside Python: a C99 module a firmware calls at 400 Hz
(:mod:`~rtlift.export.c_module`, judged by :mod:`~rtlift.export.steady` and
:mod:`~rtlift.export.vectors`) and a MATLAB file (:mod:`~rtlift.export.mat`)."""

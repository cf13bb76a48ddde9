"""The application layer, on top of everything else: the command line (:mod:`.cli`, one module
per command in :mod:`.commands`), the 400 Hz observer loop over a link (:mod:`.live`), the
lift controller and its closed loop (:mod:`.control`, :mod:`.closed_loop`, :mod:`.reference`,
:mod:`.hil_tracking`), the live view (:mod:`.view`) and the demo (:mod:`.demo`).

Nothing below imports it (``tests/test_layers.py``).
"""

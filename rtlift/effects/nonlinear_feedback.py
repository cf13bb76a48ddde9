"""The ``nonlinear_feedback`` structure: the output fed back through a static nonlinearity into the
linear block's input, tried by the generic diagnosis (:mod:`rtlift.sysid.diagnose`) in the model
structure of that name; its evidence is the residual's higher-order dependence on the input
(:func:`rtlift.residual.stats.higher_order`)."""

from __future__ import annotations

from rtlift.effects.base import Structure


class NonlinearFeedback(Structure):
    name = "nonlinear_feedback"
    row = 20
    meaning = ("the output feeds back through a static nonlinearity into the linear block's input "
               "(amplitude-dependent resonance, Duffing-like)")
    how = ("the output's deviation y from an operating point fed back through k2 y^2 + k3 y^3 into a strictly "
           "proper linear block, plus the input's direct path, all refined jointly from the ARX fit; orders 2-3 "
           "also with a Bouc-Wen hysteresis state z in the map (a restoring force with memory), kept where it "
           "holds out better")
    forms = ((name, None),)        # the model structure of the same name

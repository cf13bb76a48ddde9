"""The ``output_dynamics`` structure: a linear block after the static nonlinearity (Wiener becomes
Wiener–Hammerstein), tried by the generic diagnosis (:mod:`rtlift.sysid.diagnose`) in the
``wiener_hammerstein`` model structure; its evidence is the residual's higher-order dependence
on the input (:func:`rtlift.residual.stats.higher_order`)."""

from __future__ import annotations

from rtlift.effects.base import Structure


class OutputDynamics(Structure):
    name = "output_dynamics"
    row = 10
    meaning = ("a linear block after the static nonlinearity: Wiener becomes Wiener–Hammerstein (a balance or "
               "amplifier with its own dynamics)")
    how = "Wiener-Hammerstein re-identified jointly from the best linear approximation's pole/zero splits"
    forms = (("wiener_hammerstein", None),)

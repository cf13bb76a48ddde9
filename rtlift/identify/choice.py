"""Which lift structure ``rtlift identify`` fits (issue 31), and why.

- Records that burst at one rate (static sweep, single bursts, the training record): the
  paper's hybrid (:func:`~rtlift.identify.campaign.identify_hybrid`). Its slow part is driven by
  the commanded envelope, which is right while bursts fire at the lift-optimal rate.
- The same with burst trains (``--trains``, as ``rtlift record … campaign`` records them): the
  ``interaction`` structure (:func:`~rtlift.identify.interaction.identify_interaction`). A
  sparse train's envelope says "0.0022" between bursts seconds apart; the hybrid gives it the
  lift of 8 Hz bursting (measured on the independent plant's ``clean/`` records: ρ 0.16 on
  T = 7 t⁺, 0.02 on single bursts), the interaction structure drives its slow part with the
  momentum the bursts delivered and fits every burst pattern.

``--structure`` overrides the choice. The choice and its reason go into the model file
(``provenance.structure.choice``).

The diagnosis on it (issue 31, ``docs/results/bursts.md``): ``rtlift diagnose`` gets all 8 of the
independent plant's development cases right with the interaction model identified from the full
campaign, as with the hybrid, and 8 of 8 in the user's form (as the hybrid since the diagnosis compares
competing explanations on the level-free validation error). A ``hysteresis``
factor on this structure is driven by the flow's whole slow lift, the Wiener part plus the burst
part's slow term (:class:`rtlift.blocks.wiener._DirectionMemory`'s ``offset``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtlift.core.records import Record, burst_onsets
from rtlift.identify.campaign import Identification, IdentifyOptions, identify_hybrid
from rtlift.identify.interaction import InteractionIdentification, InteractionOptions, identify_interaction

STRUCTURES = ("paper", "interaction")


@dataclass(frozen=True)
class StructureChoice:
    """The structure identified (``paper`` or ``interaction``) and the reason, in a sentence."""

    name: str
    why: str

    def to_dict(self) -> dict[str, str]:
        return {"chosen": self.name, "why": self.why}


def _periods(trains: list[Record]) -> str:
    parts = []
    for t in trains:
        on = burst_onsets(t.cmu)
        period = f"bursts every {np.median(np.diff(on)) / t.fs_hz:.3g} s" if on.size > 1 else \
            f"{on.size} burst"
        parts.append(f"{t.name or 'train'} ({period})")
    return ", ".join(parts)


def choose_structure(trains: list[Record], requested: str | None = None) -> StructureChoice:
    """The structure for a campaign with these burst-train records (module docstring);
    ``requested`` (``--structure``) wins. ``ValueError`` for an unknown name or a train
    record without a burst."""
    if requested is not None and requested not in STRUCTURES:
        raise ValueError(f"unknown lift structure {requested!r} (known: {', '.join(STRUCTURES)})")
    empty = [t.name or "train" for t in trains if burst_onsets(t.cmu).size == 0]
    if empty:
        raise ValueError(f"no burst in the train record(s) {', '.join(empty)}")
    if requested == "paper":
        return StructureChoice("paper", "asked for (--structure paper)"
                               + (f"; the burst trains {_periods(trains)} are not fitted" if trains else ""))
    if requested == "interaction":
        return StructureChoice("interaction", "asked for (--structure interaction)"
                               + (f" with the burst trains {_periods(trains)}" if trains else " without burst trains"))
    if trains:
        return StructureChoice("interaction", f"the identification records include burst trains {_periods(trains)}: "
                               "the paper's hybrid drives its slow part with the commanded envelope and gives "
                               "sparse bursts the lift of lift-optimal bursting; the interaction structure drives "
                               "it with the momentum the bursts delivered")
    return StructureChoice("paper", "no burst-train records: every record bursts at one rate, where the paper's "
                           "hybrid (slow part from the commanded envelope) holds")


def identify_lift(static: Record, burst: Record, trains: list[Record], train: Record, structure: str | None = None,
                  *, hybrid: IdentifyOptions | None = None,
                  interaction: InteractionOptions | None = None) -> tuple[Identification | InteractionIdentification,
                                                                         StructureChoice]:
    """``rtlift identify`` on a lift campaign: the structure :func:`choose_structure` picks,
    identified with its options; the choice is recorded in ``provenance.structure``
    (``name``, ``choice``). ``ValueError`` on unusable data."""
    choice = choose_structure(trains, structure)
    if choice.name == "interaction":
        idf = identify_interaction(static, burst, trains, train, interaction)
    else:
        idf = identify_hybrid(static, burst, train, hybrid)
    idf.provenance["structure"] = {"name": choice.name, **idf.provenance["structure"], "choice": choice.to_dict()}
    return idf, choice

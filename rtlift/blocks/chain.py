"""The state of a composite streaming block: its parts' states laid end to end.

A model or block made of streaming blocks (``self.blocks``, in a fixed order) inherits
:class:`BlockChain` for ``reset``, ``state_size``, ``get_state`` and ``set_state``: the state
is ``[state of blocks[0], state of blocks[1], …]``, so a checkpoint of the whole is one array.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np


class BlockChain:
    """Mixin: the state of ``self.blocks`` (a tuple of streaming blocks) laid end to end."""

    state_name: ClassVar[str] = "model"
    """How a wrong-shape error names the state."""

    def reset(self) -> None:
        for b in self.blocks:
            b.reset()

    @property
    def state_size(self) -> int:
        return sum(b.state_size for b in self.blocks)

    def get_state(self) -> np.ndarray:
        return np.concatenate([np.atleast_1d(b.get_state()) for b in self.blocks])

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, dtype=float)
        if s.shape != (self.state_size,):
            raise ValueError(f"{self.state_name} state must have shape ({self.state_size},), got {s.shape}")
        i = 0
        for b in self.blocks:
            b.set_state(s[i:i + b.state_size])
            i += b.state_size

"""The hidden state of one hand over time: what both the glove painter and the renderer read."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata.synthetic.tasks import TASKS


@dataclass
class HandState:
    """Hidden state of one hand at T times (every array has leading dim T)."""

    task: str
    hand: str
    role: str                 # "dominant" (task profile) or "support"
    t: np.ndarray             # (T,) seconds
    phase: np.ndarray         # (T,) int8: 0 approach, 1 contact, 2 release
    force: np.ndarray         # (T,) float32 in [0,1]; exactly 0 outside contact
    closure: np.ndarray       # (T,5) float32 in [0,1], thumb..little
    hand_xy: np.ndarray       # (T,2) float32 world units (1 = image short side)
    jitter_key: int           # seeds the blob-centre jitter per glove block

    def __len__(self) -> int:
        return len(self.t)

    def frame(self, i: int) -> "HandState":
        s = slice(i, i + 1)
        return HandState(self.task, self.hand, self.role, self.t[s], self.phase[s], self.force[s],
                         self.closure[s], self.hand_xy[s], self.jitter_key)

    @property
    def profile(self) -> dict[str, float]:
        task = TASKS[self.task]
        return task.contact if self.role == "dominant" else task.support

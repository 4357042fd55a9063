"""The runner-up: the hypothesis the hybrid did not choose, carried on for a few frames.

Where the detector and the track disagree, :func:`~runtime.hybrid.policy.choose` settles it
on one frame's evidence, and a wrong pose can fit that one frame slightly better (a profile
view fits facing either way; a hidden arm fits anywhere behind the body). The pose not taken
is fitted on from its own history for up to ``frames`` frames; when it explains
``confirm_frames`` frames in a row better than the track (its badness lower by more than
``margin``), the track switches to it. A second hypothesis through the hard frames, at the
cost of one more tracker fit on the frames it lives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from depthmocap.shared.config import ConfigError, field_doc

__all__ = ["RunnerUp", "RunnerUpConfig", "runner_up_verdict"]


@dataclass
class RunnerUpConfig:
    """Carry the pose the hybrid's choice did not take (not in Wei)."""

    frames: int = field_doc(
        8, "frames the runner-up is fitted on after the choice that made it, at most"
    )
    margin: float = field_doc(
        0.2,
        "the runner-up beats the track on a frame when its badness (the failure signals "
        "over their thresholds, summed) is lower by more than this",
    )
    confirm_frames: int = field_doc(
        2, "the track switches to the runner-up after it has won this many frames in a row"
    )

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ConfigError(f"runner_up.frames must be >= 1, got {self.frames!r}")
        if not (self.margin >= 0 and math.isfinite(self.margin)):
            raise ConfigError(f"runner_up.margin must be a number >= 0, got {self.margin!r}")
        if self.confirm_frames < 1:
            raise ConfigError(f"runner_up.confirm_frames must be >= 1, got {self.confirm_frames!r}")


@dataclass(frozen=True)
class RunnerUp:
    """A pose not taken, and its own short history.

    Attributes:
        q, q_prev: (34,) its last two poses (q_prev None: the prior predicts no motion).
        index, index_prev: the stream frames they are of (index_prev None with q_prev).
        born: the frame of the choice that made it.
        wins: frames in a row it has beaten the track.
    """

    q: torch.Tensor
    q_prev: torch.Tensor | None
    index: int
    index_prev: int | None
    born: int
    wins: int = 0

    def expired(self, index: int, cfg: RunnerUpConfig) -> bool:
        """Whether frame ``index`` is past the runner-up's ``cfg.frames``."""
        return index - self.born > cfg.frames

    def moved_on(self, q: torch.Tensor, index: int, wins: int) -> RunnerUp:
        """The runner-up after its fit ``q`` (34,) of frame ``index``."""
        return RunnerUp(q, self.q, index, self.index, self.born, wins)


def runner_up_verdict(
    track_badness: float, runner_up_badness: float, wins: int, cfg: RunnerUpConfig
) -> tuple[int, bool]:
    """(wins in a row after this frame, switch to the runner-up now). A NaN badness on
    either side is no win."""
    won = runner_up_badness < track_badness - cfg.margin
    wins = wins + 1 if won else 0
    return wins, wins >= cfg.confirm_frames

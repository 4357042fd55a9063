"""Refits of one frame from many starts, screened: all starts for a few Gauss-Newton
iterations, then only the most promising for the rest.

A batched refit costs in proportion to its starts (about 1.1 ms per start and iteration on
one CPU thread), and most starts of a search are plainly wrong after a step or two: the arm
search's eight arm poses, the detector's four limb swaps. Screening them spends the later
iterations on the few that can win. The kept starts go on from where the screen left them;
their prior then pulls towards that pose rather than the start, which is the only way their
fit differs from an unscreened one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from .tracker import TrackResult

__all__ = ["Refit", "screened_refits"]

# Start poses (K, 34) and at most how many Gauss-Newton iterations (None: the tracker's) ->
# the tracker's refit of the frame from each, in order (one batched fit: ``Tracker.fit_starts``).
Refit = Callable[[torch.Tensor, "int | None"], "list[TrackResult]"]


def screened_refits(
    starts: torch.Tensor,
    refit: Refit,
    iterations: int,
    screen: int | None,
    keep: int,
    rank: Callable[[TrackResult], object],
) -> tuple[list[TrackResult], list[int]]:
    """Refits of the K ``starts`` (K, 34) for ``iterations`` Gauss-Newton steps in all.

    With ``screen`` (< ``iterations``) and ``keep`` (< K): every start is refitted for
    ``screen`` iterations, and the ``keep`` with the smallest ``rank`` (ties to the earlier
    start) for the remaining ``iterations - screen`` from there. Otherwise every start for
    all of them (``refit(starts, iterations)``).

    Returns:
        the refits, in start order, and the index of the start each came from.
    """
    K = starts.shape[0]
    if screen is None or screen >= iterations or keep >= K:
        return refit(starts, iterations), list(range(K))
    first = refit(starts, screen)
    ranks = [rank(r) for r in first]
    best = sorted(sorted(range(K), key=lambda k: ranks[k])[:keep])
    return refit(torch.stack([first[k].q for k in best]), iterations - screen), best

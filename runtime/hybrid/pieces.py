"""A computation queued in pieces on a worker thread, whose reader takes over the pieces the
worker has not started.

The size search's refits run on a low-priority worker (:mod:`runtime.hybrid.body_scale`),
and the frame that reads a sample waits for whatever of it is left (a fifth of the broad
protocol's frames over 50 ms, thirty-third session). Queued as pieces, the part the worker
has not reached runs on the reading thread while the worker finishes its own piece, so both
cores work on the wait instead of one. Which thread computes a piece does not change its
result.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor

import numpy as np

__all__ = ["PiecesInFlight"]


class PiecesInFlight:
    """``pieces`` submitted to ``pool`` in order; :meth:`result` concatenates their arrays.

    Args:
        pool: the worker (one thread takes the pieces first to last).
        pieces: callables returning arrays, concatenated in this order.
    """

    def __init__(self, pool: Executor, pieces: Sequence[Callable[[], np.ndarray]]) -> None:
        self._jobs = [(pool.submit(piece), piece) for piece in pieces]
        self.stolen = 0  # pieces the reader ran itself

    def done(self) -> bool:
        """Whether the worker has nothing of it left to run (every piece finished, or taken
        over by :meth:`result`)."""
        return all(future.done() for future, _ in self._jobs)

    def result(self) -> np.ndarray:
        """Every piece's result in order: the pieces not yet started run here, last first
        (the worker takes them first first), then the rest are waited for."""
        parts: list[np.ndarray | None] = [None] * len(self._jobs)
        for k in reversed(range(len(self._jobs))):
            future, piece = self._jobs[k]
            if future.cancel():  # not started: the worker will not run it now
                parts[k] = piece()
                self.stolen += 1
        for k, (future, _) in enumerate(self._jobs):
            if parts[k] is None:
                parts[k] = future.result()
        return np.concatenate(parts)

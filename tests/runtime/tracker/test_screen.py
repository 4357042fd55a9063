"""Screened refits (runtime.tracker.screen): all starts for a few iterations, the best for
the rest."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from depthmocap.runtime.tracker.screen import screened_refits


class _Refit:
    """A refit whose rank is the start's first value, each iteration halving its distance to
    1; records every call's starts and iteration count."""

    def __init__(self) -> None:
        self.calls: list[tuple[list[float], int | None]] = []

    def __call__(self, starts: torch.Tensor, iterations: int | None):
        self.calls.append((starts[:, 0].tolist(), iterations))
        out = []
        for s in starts:
            q = s.clone()
            q[0] = 1 + (s[0] - 1) / 2**iterations
            out.append(SimpleNamespace(q=q))
        return out


def _starts(values):
    q = torch.zeros(len(values), 34)
    q[:, 0] = torch.tensor(values)
    return q


def _rank(r):
    return float(r.q[0])


def test_without_a_screen_every_start_runs_every_iteration():
    refit = _Refit()
    out, came_from = screened_refits(_starts([5.0, 3.0, 9.0]), refit, 5, None, 2, _rank)
    assert refit.calls == [([5.0, 3.0, 9.0], 5)] and came_from == [0, 1, 2] and len(out) == 3


def test_the_screen_keeps_the_best_starts_in_order_for_the_rest():
    refit = _Refit()
    out, came_from = screened_refits(_starts([5.0, 3.0, 9.0, 2.0]), refit, 5, 2, 2, _rank)
    # After 2 iterations the ranks are 2, 1.5, 3, 1.25: starts 1 and 3 go on, 3 iterations.
    assert refit.calls == [([5.0, 3.0, 9.0, 2.0], 2), ([1.5, 1.25], 3)]
    assert came_from == [1, 3]
    assert [float(r.q[0]) for r in out] == pytest.approx([1.0625, 1.03125])  # 5 steps in all
    ties = _Refit()
    _, came_from = screened_refits(_starts([3.0, 3.0, 3.0]), ties, 3, 1, 1, _rank)
    assert came_from == [0]  # a tie goes to the earlier start


@pytest.mark.parametrize("screen, keep", [(2, 4), (5, 1), (7, 1)])
def test_nothing_is_screened_when_all_are_kept_or_the_screen_is_the_fit(screen, keep):
    refit = _Refit()
    out, came_from = screened_refits(_starts([5.0, 3.0, 9.0, 2.0]), refit, 5, screen, keep, _rank)
    assert refit.calls == [([5.0, 3.0, 9.0, 2.0], 5)] and came_from == [0, 1, 2, 3]

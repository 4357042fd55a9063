"""The hidden-arm search's screen settings (runtime.hybrid.arm_search; the search itself is
tested through the hybrid in test_hybrid, the screen in tests/runtime/tracker/test_screen)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from depthmocap.runtime.hybrid import hybrid_config
from depthmocap.runtime.hybrid.arm_search import ArmSearch
from depthmocap.runtime.hybrid.config import ArmSearchConfig, HybridError
from depthmocap.shared.body import BodyShape


def test_the_search_screens_its_starts_by_their_badness():
    cfg = ArmSearchConfig(screen_iterations=1, screen_keep=1)
    search = ArmSearch(cfg, BodyShape.default(), iterations=3)
    calls = []

    def refit(starts, iterations):
        calls.append((len(starts), iterations))
        return [SimpleNamespace(q=s, signals=float(s[0])) for s in starts]

    starts = torch.zeros(3, 34)
    starts[:, 0] = torch.tensor([2.0, 1.0, 3.0])
    out = search._refits(starts, refit, lambda signals: -signals)  # the largest is best
    assert calls == [(3, 1), (1, 2)] and float(out[0].q[0]) == 3.0


@pytest.mark.parametrize("cfg", [{"screen_iterations": 0}, {"screen_keep": 0}])
def test_bad_screens_are_rejected(cfg):
    with pytest.raises(HybridError, match="screen"):
        hybrid_config({"arm_search": cfg})

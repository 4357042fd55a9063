"""The tracker's pixel regions (runtime.tracker.regions): pixel sampling that is stable when
the mask changes."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker.regions import sample_pixels

pytestmark = pytest.mark.usefixtures("one_thread")


class TestSamplePixels:
    def test_samples_stay_put_when_the_mask_changes(self):
        order = torch.randperm(60 * 80, generator=torch.Generator().manual_seed(0))
        mask = torch.zeros(60 * 80, dtype=torch.bool)
        mask[order[:1800]] = True
        grown = mask.clone()
        grown[order[1800:1850]] = True  # 50 more pixels; the stride stays ceil(1850 / 500) = 4
        a, total, ratio = sample_pixels(mask.reshape(1, 60, 80), 500)
        b, _, _ = sample_pixels(grown.reshape(1, 60, 80), 500)
        assert total == 1800 and ratio == pytest.approx(1800 / len(a))
        assert abs(len(a) - 450) < 60  # about total / stride
        kept = {tuple(r) for r in b.tolist()}
        assert all(tuple(r) in kept for r in a.tolist())  # every earlier sample is still sampled
        few, count, one = sample_pixels(mask.reshape(1, 60, 80), 5000)
        assert len(few) == count == 1800 and one == 1.0

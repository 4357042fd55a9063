"""The tracker's pixel regions (runtime.tracker.regions): pixel sampling that is stable when
the mask changes."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker.regions import batch_slots, sample_pixels

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
        assert total.tolist() == [1800]
        assert ratio.dtype == torch.float64 and bool((ratio == 1800 / len(a)).all())  # exact
        assert abs(len(a) - 450) < 60  # about total / stride
        kept = {tuple(r) for r in b.tolist()}
        assert all(tuple(r) in kept for r in a.tolist())  # every earlier sample is still sampled
        few, count, one = sample_pixels(mask.reshape(1, 60, 80), 5000)
        assert len(few) == int(count[0]) == 1800 and bool((one == 1.0).all())

    def test_the_cap_is_per_mask(self):
        """Each mask of a batch is sampled as it would be alone (a batch of starts on one
        frame must not thin out each start's pixels)."""
        gen = torch.Generator().manual_seed(1)
        masks = torch.rand(3, 60, 80, generator=gen) < torch.tensor([0.5, 0.05, 0.3])[:, None, None]
        idx, total, ratio = sample_pixels(masks, 400)
        assert total.tolist() == masks.sum((1, 2)).tolist()
        for b in range(3):
            alone, _, r_alone = sample_pixels(masks[b : b + 1], 400)
            mine = idx[idx[:, 0] == b]
            assert torch.equal(mine[:, 1:], alone[:, 1:])
            assert torch.allclose(ratio[idx[:, 0] == b], r_alone)
        assert bool((idx[1:, 0] >= idx[:-1, 0]).all())  # sorted by mask


class TestBatchSlots:
    def test_groups_rows_by_pose(self):
        batch = torch.tensor([2, 0, 2, 2, 0])
        slots, real = batch_slots(batch, 4)
        assert slots.shape == (4, 3)
        assert slots[real].tolist() == [1, 4, 0, 2, 3]
        assert real.sum(1).tolist() == [2, 0, 3, 0]
        empty, none = batch_slots(torch.zeros(0, dtype=torch.long), 2)
        assert empty.shape == (2, 0) and none.shape == (2, 0)

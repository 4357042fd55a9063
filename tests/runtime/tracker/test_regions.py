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

    @pytest.mark.parametrize("cap", [0, 400])
    def test_the_torch_sampler_on_every_device(self, device, cap):
        """The torch sampler (the GPU's) keeps the rows, counts and ratios of the CPU's."""
        from depthmocap.runtime.tracker.regions import sample_pixels_torch

        gen = torch.Generator().manual_seed(2)
        masks = torch.rand(3, 61, 83, generator=gen) < torch.tensor([0.6, 0.0, 0.2])[:, None, None]
        want = sample_pixels(masks, cap)
        got = sample_pixels_torch(masks.to(device), cap)
        for g, w in zip(got, want, strict=True):
            assert g.device.type == device.type and g.dtype == w.dtype and torch.equal(g.cpu(), w)


class TestBatchSlots:
    def test_groups_rows_by_pose(self):
        batch = torch.tensor([2, 0, 2, 2, 0])
        slots, real = batch_slots(batch, 4)
        assert slots.shape == (4, 3)
        assert slots[real].tolist() == [1, 4, 0, 2, 3]
        assert real.sum(1).tolist() == [2, 0, 3, 0]
        empty, none = batch_slots(torch.zeros(0, dtype=torch.long), 2)
        assert empty.shape == (2, 0) and none.shape == (2, 0)

    def test_on_every_device(self, device):
        batch = torch.tensor([1, 1, 0, 1], device=device)
        slots, real = batch_slots(batch, 3)
        assert slots.device.type == device.type
        assert slots[real].tolist() == [2, 0, 1, 3] and real.sum(1).tolist() == [1, 3, 0]


class TestCompiledSampler:
    """The numba sampler (the CPU path) against the torch code it stands in for."""

    @pytest.mark.parametrize("cap", [0, 1, 7, 400, 5000])
    def test_the_same_rows_counts_and_ratios(self, cap):
        pytest.importorskip("numba")
        from depthmocap.runtime.tracker.regions import sample_pixels_torch
        from depthmocap.runtime.tracker.sampling_kernel import sample_pixels_cpu

        gen = torch.Generator().manual_seed(cap)
        density = torch.tensor([0.6, 0.0, 0.02, 0.3])[:, None, None]  # one mask empty
        masks = torch.rand(4, 61, 83, generator=gen) < density
        # The kernel samples within the rows and columns holding True pixels: a patch inside,
        # single pixels in the far and near corners.
        patch = torch.zeros(3, 61, 83, dtype=torch.bool)
        patch[0, 20:30, 40:50] = masks[0, 20:30, 40:50]
        patch[1, 60, 82] = patch[2, 0, 0] = True
        views = (masks, masks[:1].expand(3, -1, -1), masks[:, ::2, 1::3], masks[:0], patch)
        for m in views:
            got = sample_pixels_cpu(m, cap)
            want = sample_pixels_torch(m, cap)
            for g, w in zip(got, want, strict=True):
                assert g.dtype == w.dtype and torch.equal(g, w)
        # The public function on a CPU mask gives the same (it takes the compiled path).
        for g, w in zip(sample_pixels(masks, cap), sample_pixels_torch(masks, cap), strict=True):
            assert torch.equal(g, w)

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_rendered_points_the_same_as_torch(self, dtype):
        pytest.importorskip("numba")
        from types import SimpleNamespace

        from depthmocap.runtime.tracker.regions import pixel_rays, rendered_points
        from depthmocap.shared.camera import Intrinsics

        gen = torch.Generator().manual_seed(2)
        intr = Intrinsics.kinect_v1(160)
        depth = (1.0 + 3.0 * torch.rand(2, intr.height, intr.width, generator=gen)).to(dtype)
        segment = torch.randint(-1, 16, depth.shape, generator=gen)
        idx, _, _ = sample_pixels(torch.rand(depth.shape, generator=gen) < 0.3, 500)
        points, seg = rendered_points(SimpleNamespace(depth=depth, segment=segment), idx, intr)
        b, v, u = idx.unbind(1)
        want = depth[b, v, u][:, None] * pixel_rays(idx, intr, dtype)
        assert points.dtype == dtype and torch.equal(points, want)
        assert torch.equal(seg, segment[b, v, u])
        # With autograd the torch code runs (the compiled loop has no gradient).
        grad_depth = depth.clone().requires_grad_(True)
        p, _ = rendered_points(SimpleNamespace(depth=grad_depth, segment=segment), idx, intr)
        assert p.requires_grad and torch.equal(p.detach(), want)


class TestClassify:
    @pytest.mark.parametrize("expanded", [True, False])
    @pytest.mark.parametrize("occlusion", [True, False])
    def test_compiled_regions_equal_torch(self, monkeypatch, expanded, occlusion):
        """The compiled pass (the CPU path) gives torch's regions bit for bit, also for an
        observation that is a stride-0 view of one frame (a batch of starts) and for depth
        differences at the gate itself (compared in float32, as torch does)."""
        pytest.importorskip("numba")
        from types import SimpleNamespace

        from depthmocap.runtime.tracker import regions

        g = torch.Generator().manual_seed(0)
        B, H, W = 3, 37, 29
        depth = torch.rand(1 if expanded else B, H, W, generator=g) * 3
        depth[depth < 0.8] = 0
        depth = depth.expand(B, H, W) if expanded else depth
        silhouette = (depth > 0) | (torch.rand(depth.shape, generator=g) > 0.9)
        obs = SimpleNamespace(depth=depth, valid=depth > 0, silhouette=silhouette)
        rendered = torch.rand(B, H, W, generator=g) * 3
        rendered[rendered < 1] = 0
        rendered[:, 0, :8] = depth[:, 0, :8] + 0.1  # differences at the gate
        render = SimpleNamespace(depth=rendered, mask=rendered > 0)
        compiled = regions.classify(render, obs, 0.1, occlusion)
        monkeypatch.setattr(regions, "compiled_float32", lambda *a, **k: None)
        reference = regions.classify(render, obs, 0.1, occlusion)
        for field in ("good", "b1", "b2_front", "b2_behind", "b3", "depth_diff"):
            got, want = getattr(compiled, field), getattr(reference, field)
            assert got.dtype == want.dtype and torch.equal(got, want), field
        assert int(compiled.good.sum()) > 0 and int(compiled.b3.sum()) > 0

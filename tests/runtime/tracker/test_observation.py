"""The tracker's observation (runtime.tracker.observation): distance transform, depth pooling,
the person's window, the automatic downsampling factor, and observing in a window."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker.observation import (
    automatic_factor,
    distance_to_mask,
    distance_to_mask_torch,
    observe,
    person_window,
    pool_depth,
)
from depthmocap.shared.camera import Intrinsics

INTR = Intrinsics.kinect_v1(320)

pytestmark = pytest.mark.usefixtures("one_thread")


class TestDistanceToMask:
    def test_matches_brute_force(self):
        g = torch.Generator().manual_seed(1)
        mask = torch.rand(2, 17, 23, generator=g) > 0.93
        got = distance_to_mask(mask, 6.0)
        v, u = torch.meshgrid(torch.arange(17.0), torch.arange(23.0), indexing="ij")
        for b in range(2):
            pts = mask[b].nonzero().float()
            d = ((v[..., None] - pts[:, 0]) ** 2 + (u[..., None] - pts[:, 1]) ** 2).sqrt().amin(-1)
            assert torch.allclose(got[b], d.clamp_max(6.0), atol=1e-5)
        assert float(distance_to_mask(torch.zeros(1, 5, 5, dtype=torch.bool), 4.0).min()) == 4.0

    def test_compiled_loop_is_torch_to_the_bit(self):
        """numba's loop against torch's shifts: sparse, dense, empty, full, single-row and
        single-column masks, caps below one pixel to beyond the image, as the tracker uses
        them (float32). The square roots are torch's own (sqrt(37) is not correctly rounded
        in every build), so they match wherever torch runs."""
        pytest.importorskip("depthmocap.runtime.tracker.distance_kernel")
        g = torch.Generator().manual_seed(2)
        masks = [
            torch.rand(2, 40, 37, generator=g) > 0.97,
            torch.rand(1, 60, 60, generator=g) > 0.5,
            torch.rand(1, 50, 50, generator=g) > 0.995,
            torch.zeros(1, 9, 5, dtype=torch.bool),
            torch.ones(1, 3, 4, dtype=torch.bool),
            torch.rand(3, 1, 30, generator=g) > 0.9,
            torch.rand(1, 30, 1, generator=g) > 0.9,
        ]
        for mask in masks:
            for cap in (0.0, 0.5, 3.5, 10.0, 12.0, 25.0):
                got = distance_to_mask(mask, cap)
                assert got.dtype == torch.float32
                assert torch.equal(got, distance_to_mask_torch(mask, cap)), (mask.shape, cap)


class TestPoolDepth:
    def test_golden(self):
        """Pooling takes the block's corner pixel and fills holes in the mask."""
        depth = torch.tensor([[[2.0, 2.1, 3.0, 3.0], [2.2, 2.3, 3.0, 3.0]]])
        depth[0, 0, 2] = 0.0  # missing reading at a block's corner pixel
        mask = depth > 0
        pooled, sil = pool_depth(depth, mask, 2)
        assert pooled.tolist() == [[[2.0, 0.0]]] and sil.tolist() == [[[True, False]]]
        mask[0, 0, 2] = True
        pooled, sil = pool_depth(depth, mask, 2)
        assert pooled.tolist() == [[[2.0, 3.0]]] and sil.tolist() == [[[True, True]]]


class TestPersonWindow:
    def test_golden(self):
        """The window grows the person's box and keeps the pixel grid."""
        mask = torch.zeros(2, 60, 80, dtype=torch.bool)
        mask[0, 20:30, 31:41] = True  # 10 x 10
        mask[1, 25:40, 35:37] = True  # the box spans both frames: rows 20-39, columns 31-40
        assert person_window(mask, 1, 0.25, 2) == (31 - 5, 41 + 5, 20 - 5, 40 + 5)
        # Corner on the factor's grid; at least min_margin_px working pixels (2 x 6 stream
        # pixels).
        assert person_window(mask, 2, 0.0, 6) == (18, 53, 8, 52)
        # Clipped to the image; nothing to frame without a person.
        assert person_window(mask, 1, 3.0, 0) == (0, 80, 0, 60)
        assert person_window(torch.zeros(1, 5, 5, dtype=torch.bool), 2, 0.25, 2) is None


class TestAutomaticFactor:
    def test_golden(self):
        """The factor follows the person's size."""
        mask = torch.zeros(1, 240, 320, dtype=torch.bool)
        mask[0, :100, :25] = True  # 2,500 pixels
        assert automatic_factor(mask, 2500) == 1
        assert automatic_factor(mask, 600) == 2  # sqrt(4.2) rounds to 2
        assert automatic_factor(mask, 100) == 5
        assert automatic_factor(mask & False, 2500) == 1


class TestObserve:
    @pytest.mark.parametrize("factor", [1, 2])
    def test_window_is_the_whole_image_cut(self, factor, render_sequence):
        body, truth, depth, mask = render_sequence("wave", 1)
        full = observe(depth, mask, INTR, factor, 6.0)
        u0, u1, v0, v1 = person_window(mask, factor, 0.25, 8)
        cut = observe(depth, mask, INTR, factor, 6.0, (u0, u1, v0, v1))
        i0, j0 = v0 // factor, u0 // factor
        h, w = cut.depth.shape[-2:]
        for name in ("depth", "silhouette", "valid", "points", "distance"):
            a, b = getattr(full, name)[:, i0 : i0 + h, j0 : j0 + w], getattr(cut, name)
            assert torch.allclose(a.double(), b.double(), atol=1e-6), name
        assert cut.intr.cx == pytest.approx(full.intr.cx - j0) and cut.intr.fy == full.intr.fy

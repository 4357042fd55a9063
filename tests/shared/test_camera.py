import pytest
import torch
from depthmocap.shared.camera import (
    Intrinsics,
    depth_to_points,
    masked_points,
    pixel_grid,
    points_to_pixels,
)


def test_kinect_defaults():
    k640 = Intrinsics.kinect_v1(640)
    assert (k640.fx, k640.cx, k640.cy) == (575.8, 319.5, 239.5)
    k320 = Intrinsics.kinect_v1()
    assert (k320.width, k320.height) == (320, 240)
    assert k320.fx == pytest.approx(287.9) and k320.cx == pytest.approx(159.5)
    assert k320.cy == pytest.approx(119.5)


def test_depth_points_pixels_round_trip(device, dtype):
    intr = Intrinsics.kinect_v1(160)
    g = torch.Generator().manual_seed(0)
    depth = (0.8 + 3.0 * torch.rand(2, 120, 160, generator=g)).to(device, dtype)
    pts = depth_to_points(depth, intr)
    assert pts.shape == (2, 120, 160, 3)
    uv = points_to_pixels(pts, intr)
    u, v = pixel_grid(120, 160, dtype, device)
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    assert torch.allclose(uv[..., 0], u.expand_as(uv[..., 0]), atol=tol)
    assert torch.allclose(uv[..., 1], v.expand_as(uv[..., 1]), atol=tol)
    assert torch.equal(pts[..., 2], depth)


def test_golden_projection():
    intr = Intrinsics.kinect_v1(640)
    uv = points_to_pixels(torch.tensor([[0.5, -0.25, 2.0]], dtype=torch.float64), intr)
    assert torch.allclose(
        uv, torch.tensor([[319.5 + 575.8 * 0.25, 239.5 - 575.8 * 0.125]], dtype=torch.float64)
    )


def test_no_reading_gives_origin():
    intr = Intrinsics.kinect_v1(160)
    pts = depth_to_points(torch.zeros(1, 120, 160), intr)
    assert torch.count_nonzero(pts) == 0


def test_size_mismatch_raises():
    with pytest.raises(ValueError, match="intrinsics are for 240x320"):
        depth_to_points(torch.zeros(1, 120, 160), Intrinsics.kinect_v1(320))


def test_validate():
    with pytest.raises(ValueError, match="focal"):
        Intrinsics(10, 10, -1.0, 1.0, 5.0, 5.0).validate()
    with pytest.raises(ValueError, match="size"):
        Intrinsics(0, 10, 1.0, 1.0, 5.0, 5.0).validate()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_masked_points_are_the_image_points_of_the_mask(device, dtype):
    """The person's points alone are the whole image's points at the mask, to the bit."""
    intr = Intrinsics.kinect_v1(160)
    gen = torch.Generator().manual_seed(0)
    depth = (0.5 + 4 * torch.rand(intr.height, intr.width, generator=gen)).to(device, dtype)
    depth[::7] = 0.0  # rows without readings
    mask = (torch.rand(intr.height, intr.width, generator=gen) > 0.7).to(device)
    got = masked_points(depth, mask, intr)
    assert got.shape == (int(mask.sum()), 3) and got.dtype == dtype
    assert torch.equal(got, depth_to_points(depth[None], intr)[0][mask])
    assert masked_points(depth, torch.zeros_like(mask), intr).shape == (0, 3)
    with pytest.raises(ValueError, match="must both be"):
        masked_points(depth[:-1], mask[:-1], intr)
    with pytest.raises(ValueError, match="must both be"):
        masked_points(depth, mask[:, :-1], intr)

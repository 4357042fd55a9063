"""Person segmentation on synthetic scenes (person box + hand in front of a floor and a wall,
with holes) and, when ../shared is present, on real Kinect v1 frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.runtime.segmentation import SegmentationConfig, fit_floor_plane, segment_person
from depthmocap.shared.camera import Intrinsics, depth_to_points

INTR = Intrinsics.kinect_v1(320)
CAM_HEIGHT = 1.0  # camera 1 m above the floor (y points down, so the floor is y = +1)


def scene(
    pitch_deg: float = 0.0,
    person: bool = True,
    hand: bool = True,
    wall_z: float = 4.0,
    person_z: float = 2.5,
    floor: bool = True,
    arm_across: bool = False,
):
    """Ray-cast a depth image (metres) and the true person pixels of a simple room.

    World frame = camera frame before the camera is pitched down by ``pitch_deg``: a floor at
    y = 1, a wall at z = ``wall_z``, a person slab 0.5 m wide standing on the floor with its
    front at ``person_z``, a 12 cm hand held 40 cm in front of the chest. ``arm_across``: a
    forearm held 30 cm in front of the hips, the legs below it 8 cm behind the trunk (the
    arm cuts them off from the trunk, and they are too large to count as a hand).
    """
    u, v = np.meshgrid(np.arange(INTR.width), np.arange(INTR.height))
    d = np.stack([(u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy, np.ones(u.shape)], -1)
    a = math.radians(pitch_deg)  # pitch down: camera forward axis tilts towards +y
    rot = np.array([[1, 0, 0], [0, math.cos(a), math.sin(a)], [0, -math.sin(a), math.cos(a)]])
    dw = d @ rot.T  # ray directions in the world, parametrized by camera z
    depth = np.full(u.shape, np.inf)
    label = np.zeros(u.shape, dtype=np.int8)  # 1 person, 2 background

    def hit(t, ok, lab):
        nonlocal depth
        closer = ok & (t > 0) & (t < depth)
        depth = np.where(closer, t, depth)
        label[closer] = lab

    with np.errstate(divide="ignore", invalid="ignore"):
        if floor:
            hit(CAM_HEIGHT / dw[..., 1], dw[..., 1] > 0, 2)
        hit(wall_z / dw[..., 2], dw[..., 2] > 0, 2)
        boxes = []
        if person and arm_across:
            boxes.append((person_z, (-0.25, 0.25), (-0.75, 0.2)))
            boxes.append((person_z + 0.08, (-0.25, 0.25), (0.2, CAM_HEIGHT)))
            boxes.append((person_z - 0.3, (-0.35, 0.35), (0.15, 0.25)))
        elif person:
            boxes.append((person_z, (-0.25, 0.25), (-0.75, CAM_HEIGHT)))
        if person and hand:
            boxes.append((person_z - 0.4, (0.1, 0.22), (-0.1, 0.02)))
        for z, (x0, x1), (y0, y1) in boxes:
            t = z / dw[..., 2]
            x, y = dw[..., 0] * t, dw[..., 1] * t
            hit(t, (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1), 1)
    depth = np.where(np.isfinite(depth), depth, 0.0)
    # World height above the floor, to know which person pixels are within the floor band.
    height = CAM_HEIGHT - (dw[..., 1] * depth)
    return torch.tensor(depth, dtype=torch.float32), torch.tensor(label == 1), height


def test_person_found_floor_and_wall_excluded():
    depth, truth, height = scene()
    mask = segment_person(depth, INTR)
    assert mask.shape == depth.shape and mask.dtype == torch.bool
    assert not (mask & ~truth).any(), "floor or wall pixels in the mask"
    body = truth & torch.as_tensor(height > 0.08)  # feet within the floor band may go
    assert (mask & body).sum() / body.sum() > 0.99
    # The hand in front of the chest is a separate component joined to the person.
    hand_px = truth & (depth < 2.2) & (depth > 0)
    assert hand_px.any() and mask[hand_px].all()


def test_legs_cut_off_by_an_arm_in_front_stay_with_the_person():
    depth, truth, height = scene(arm_across=True, hand=False)
    mask = segment_person(depth, INTR)
    assert not (mask & ~truth).any(), "floor or wall pixels in the mask"
    body = truth & torch.as_tensor(height > 0.08)
    assert (mask & body).sum() / body.sum() > 0.99


@pytest.mark.parametrize("pitch", [0.0, 20.0])
def test_floor_plane_fit_matches_geometry(pitch):
    depth, _, _ = scene(pitch_deg=pitch)
    cfg = SegmentationConfig()
    points = depth_to_points(depth[None], INTR)
    normal, centre, found = fit_floor_plane(points, depth[None] > 0, cfg)
    assert found.all()
    a = math.radians(pitch)
    up = torch.tensor([0.0, -math.cos(a), -math.sin(a)])  # world up seen from the pitched camera
    assert torch.dot(normal[0], up) > math.cos(math.radians(2.0))
    # The floor is CAM_HEIGHT below the camera centre.
    assert abs(float(torch.dot(normal[0], centre[0])) + CAM_HEIGHT) < 0.02


def test_tilted_camera_still_segments():
    depth, truth, height = scene(pitch_deg=20.0)
    mask = segment_person(depth, INTR)
    body = truth & torch.as_tensor(height > 0.08)
    assert not (mask & ~truth).any()
    assert (mask & body).sum() / body.sum() > 0.99


def test_no_floor_in_view_keeps_whole_person():
    # Upper body only (like the real frames): no plane may be cut through the torso.
    depth, truth, _ = scene(floor=False, wall_z=30.0)
    cfg = SegmentationConfig(max_depth_m=10.0)
    mask = segment_person(depth, INTR, cfg)
    assert torch.equal(mask, truth)


@pytest.mark.parametrize(
    "make",
    [
        lambda d: torch.zeros_like(d),
        lambda d: torch.full_like(d, float("nan")),
        lambda d: scene(person=False)[0],  # floor and wall only
    ],
    ids=["zeros", "nan", "empty-room"],
)
def test_frames_without_person_give_empty_mask(make):
    depth = make(scene()[0])
    assert not segment_person(depth, INTR).any()


def test_holes_and_nan_inside_person():
    depth, truth, height = scene()
    g = torch.Generator().manual_seed(1)
    holes = torch.rand(depth.shape, generator=g) < 0.1
    depth = depth.clone()
    depth[holes & truth] = float("nan")
    depth[holes & ~truth] = 0.0
    mask = segment_person(depth, INTR)
    assert not mask[holes].any(), "pixels without a reading are never in the mask"
    body = truth & torch.as_tensor(height > 0.08) & ~holes
    assert (mask & body).sum() / body.sum() > 0.98
    assert not (mask & ~truth).any()


def test_batch_matches_single_images(device):
    frames = [scene()[0], torch.zeros(INTR.height, INTR.width), scene(pitch_deg=20.0)[0]]
    batch = segment_person(torch.stack(frames).to(device), INTR)
    assert batch.device.type == device.type
    for i, f in enumerate(frames):
        assert torch.equal(batch[i].cpu(), segment_person(f, INTR))


def test_person_near_wall_is_not_merged_with_wall():
    depth, truth, height = scene(wall_z=2.9, person_z=2.5)
    mask = segment_person(depth, INTR)
    assert not (mask & ~truth).any()
    assert mask.sum() > 0.9 * (truth & torch.as_tensor(height > 0.08)).sum()


def test_bad_shape_is_rejected():
    with pytest.raises(ValueError, match="depth must be"):
        segment_person(torch.zeros(10, 10), INTR)


def test_real_kinect_frames(shared_data):
    """Real Kinect v1 frames (Skeltrack test data, 640x480, background already zeroed)."""
    files = sorted((shared_data / "kinect" / "skeltrack").glob("*.u16"))
    if not files:
        pytest.skip("no Skeltrack frames")
    intr = Intrinsics.kinect_v1(640)
    depth_mm = np.stack([np.fromfile(f, dtype="<u2").reshape(480, 640) for f in files])
    masks = segment_person(torch.from_numpy(depth_mm.astype(np.float32) * 1e-3), intr).numpy()
    for f, d, m in zip(files, depth_mm, masks):
        z = d[m] * 1e-3
        rows, cols = np.nonzero(m)
        assert m.sum() > 0.05 * m.size, f"{f.name}: person too small ({m.sum()} px)"
        assert (d[m] > 0).all()
        assert 0.6 < np.median(z) < 2.5, f"{f.name}: person at {np.median(z):.2f} m"
        assert np.percentile(z, 95) - np.percentile(z, 5) < 1.0, f"{f.name}: not one body"
        assert 0.2 * 640 < cols.mean() < 0.8 * 640, f"{f.name}: person not central"
        # Person height in the image: upper bodies reach well up (not a floor strip).
        assert rows.min() < 0.4 * 480, f"{f.name}: no head in the mask"


def test_no_floor_plane_in_a_floorless_scene():
    depth, _, _ = scene(floor=False, wall_z=3.5)
    points = depth_to_points(depth[None], INTR)
    _, _, found = fit_floor_plane(points, depth[None] > 0, SegmentationConfig())
    assert not found.any()

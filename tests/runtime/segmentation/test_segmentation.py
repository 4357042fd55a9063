"""Person segmentation on synthetic scenes (person box + hand in front of a floor and a wall,
with holes) and, when ../shared is present, on real Kinect v1 frames; choosing the person
among plausible components (shape, continuity) and what a stream carries between frames."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch
from depthmocap.runtime.segmentation import (
    PersonSegmenter,
    SegmentationConfig,
    fit_floor_plane,
    segment_person,
)
from depthmocap.runtime.segmentation.floor import remove_floor
from depthmocap.runtime.segmentation.selection import (
    component_solidity,
    person_likeness,
    person_scores,
)
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
    figure: bool = False,
    objects: tuple = (),
):
    """Ray-cast a depth image (metres) and the true person pixels of a simple room.

    World frame = camera frame before the camera is pitched down by ``pitch_deg``: a floor at
    y = 1, a wall at z = ``wall_z``, a person slab 0.5 m wide standing on the floor with its
    front at ``person_z``, a 12 cm hand held 40 cm in front of the chest. ``arm_across``: a
    forearm held 30 cm in front of the hips, the legs below it 8 cm behind the trunk (the
    arm cuts them off from the trunk, and they are too large to count as a hand). ``figure``:
    the person as head, trunk, arms held out and legs apart instead of a slab. ``objects``:
    background slabs ``(z, (x0, x1), (y0, y1))``, e.g. a box standing on the floor.
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
        elif person and figure:
            boxes.append((person_z, (-0.1, 0.1), (-0.75, -0.5)))  # head
            boxes.append((person_z, (-0.2, 0.2), (-0.5, 0.1)))  # trunk
            boxes.append((person_z, (-0.55, 0.55), (-0.45, -0.37)))  # arms held out
            boxes.append((person_z, (-0.2, -0.05), (0.1, CAM_HEIGHT)))  # legs
            boxes.append((person_z, (0.05, 0.2), (0.1, CAM_HEIGHT)))
        elif person:
            boxes.append((person_z, (-0.25, 0.25), (-0.75, CAM_HEIGHT)))
        if person and hand:
            boxes.append((person_z - 0.4, (0.1, 0.22), (-0.1, 0.02)))
        for lab, slabs in ((1, boxes), (2, objects)):
            for z, (x0, x1), (y0, y1) in slabs:
                t = z / dw[..., 2]
                x, y = dw[..., 0] * t, dw[..., 1] * t
                hit(t, (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1), lab)
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


# --- Choosing the person (selection) and the stream's memory (PersonSegmenter) ---

# A box 0.55 m wide and 1.5 m high standing on the floor right of the person, nearer the
# camera: a larger frontal area than the person's (0.83 against 0.62 m^2).
BOX = (2.3, (0.7, 1.25), (CAM_HEIGHT - 1.5, CAM_HEIGHT))
# A cupboard 0.65 m wide and 1.65 m high: larger than the slab person too (1.07 against 0.88).
CUPBOARD = (2.3, (0.6, 1.25), (CAM_HEIGHT - 1.65, CAM_HEIGHT))


def _solidity_of(image: np.ndarray, erosion_px: int = 0) -> float:
    count, labels, stats, _ = cv2.connectedComponentsWithStats(image.astype(np.uint8), 4)
    assert count == 2
    return float(component_solidity(labels, stats, np.array([1]), cv2, erosion_px)[0])


def test_a_ragged_edge_does_not_make_a_box_look_like_a_person():
    """A box whose lower edge trails one-pixel spurs of flying pixels: measured as it is, the
    spurs swell its hull; without its one-pixel fringe it is a box again. A cross keeps its
    shape either way, and a component the erosion would remove is measured as it is."""
    box = np.zeros((80, 100), bool)
    box[10:50, 10:90] = True
    for x in range(12, 88, 4):  # spurs 1 px wide, 3-12 px long
        box[50 : 53 + (x * 7) % 10, x] = True
    assert _solidity_of(box) < 0.9
    assert _solidity_of(box, erosion_px=1) > 0.95
    cross = np.zeros((60, 60), bool)
    cross[5:55, 26:34] = True
    cross[20:28, 5:55] = True
    assert _solidity_of(cross, erosion_px=1) < 0.5
    line = np.zeros((20, 20), bool)
    line[10, 2:18] = True
    assert _solidity_of(line, erosion_px=1) == pytest.approx(_solidity_of(line))


def test_solidity_golden_values():
    rect = np.zeros((60, 80), bool)
    rect[10:50, 20:60] = True
    assert _solidity_of(rect) == pytest.approx(1.0, abs=0.02)
    # An L of three 10 x 10 squares: hull = 20 x 20 square less a 10 x 10 half-square.
    ell = np.zeros((40, 40), bool)
    ell[10:30, 10:20] = True
    ell[20:30, 20:30] = True
    assert _solidity_of(ell) == pytest.approx(300 / 350, abs=0.03)
    # A cross (a T-pose): far from convex.
    cross = np.zeros((60, 60), bool)
    cross[5:55, 27:33] = True
    cross[20:26, 5:55] = True
    assert _solidity_of(cross) < 0.5


def test_likeness_ramp():
    cfg = SegmentationConfig(person_max_solidity=0.8, convex_solidity=0.9, convex_weight=0.05)
    got = person_likeness(np.array([0.5, 0.8, 0.85, 0.9, 1.0]), cfg)
    np.testing.assert_allclose(got, [1.0, 1.0, 0.525, 0.05, 0.05])


def test_scores_favour_the_previous_person():
    cfg = SegmentationConfig(continuity_overlap=0.3, continuity_gain=4.0)
    area, solidity = np.array([0.3, 0.8]), np.array([0.6, 0.6])
    assert person_scores(area, solidity, np.zeros(2), cfg).argmax() == 1
    assert person_scores(area, solidity, np.array([0.9, 0.0]), cfg).argmax() == 0
    # Continuity does not save a candidate that is far worse (recovery from a wrong choice).
    assert person_scores(np.array([0.05, 0.8]), solidity, np.array([0.9, 0.0]), cfg).argmax() == 1


def test_a_larger_box_is_not_the_person():
    depth, truth, height = scene(figure=True, hand=False, objects=(BOX,))
    mask = segment_person(depth, INTR)
    assert not (mask & ~truth).any(), "the box (or floor, wall) in the mask"
    body = truth & torch.as_tensor(height > 0.08)
    assert (mask & body).sum() / body.sum() > 0.99
    # With shape ignored (every component equally person-like), the box would win.
    flat = SegmentationConfig(convex_weight=1.0)
    assert not (segment_person(depth, INTR, flat) & truth).any()


def test_stream_keeps_its_person_when_a_larger_object_appears():
    # A slab person (convex, as the box): on its own the larger box would be chosen.
    alone, truth, _ = scene(hand=False)
    both, _, _ = scene(hand=False, objects=(CUPBOARD,))
    assert not (segment_person(both, INTR) & truth).any()
    seg = PersonSegmenter()
    assert (seg(alone, INTR) & truth).sum() > 0.9 * truth.sum()
    assert torch.equal(seg(both, INTR), seg(alone, INTR) & truth)
    seg.reset()  # a new start: the frame alone again
    assert not (seg(both, INTR) & truth).any()


def test_stream_keeps_the_floor_when_a_frame_fit_fails():
    depth, truth, height = scene(hand=False)
    z = depth.numpy()[None].astype(np.float32)
    valid = z > 0
    ok = SegmentationConfig()
    kept, floor = remove_floor(z, valid, INTR, ok)
    assert floor[2].all()
    floor_px = valid & ~kept
    assert floor_px.sum() > 1000
    refused = SegmentationConfig(floor_min_depth_span_m=100.0)  # no fit passes its checks
    none, (_, _, found) = remove_floor(z, valid, INTR, refused)
    assert not found.any() and np.array_equal(none, valid)
    again, (_, _, found) = remove_floor(z, valid, INTR, refused, floor)
    assert found.all() and np.array_equal(again, kept)
    # A previous floor that no longer explains the frame (the camera moved) is not used.
    normal, centre, was = floor
    moved = (normal, centre + 0.5 * normal, was)
    _, (_, _, found) = remove_floor(z, valid, INTR, refused, moved)
    assert not found.any()
    off = SegmentationConfig(floor_min_depth_span_m=100.0, keep_floor=False)
    _, (_, _, found) = remove_floor(z, valid, INTR, off, floor)
    assert not found.any()


def test_segmenter_forgets_on_another_camera():
    alone, truth, _ = scene(hand=False)
    both, _, _ = scene(hand=False, objects=(CUPBOARD,))
    seg = PersonSegmenter()
    seg(alone, INTR)
    other = type(INTR)(INTR.width, INTR.height, INTR.fx, INTR.fy, INTR.cx + 0.5, INTR.cy)
    assert not (seg(both, other) & truth).any()


def test_memory_of_another_batch_or_size_is_ignored():
    from depthmocap.runtime.segmentation.person import segment_person_in_stream

    alone, truth, _ = scene(hand=False)
    _, memory = segment_person_in_stream(torch.stack([alone, alone]), INTR)
    single = segment_person(alone, INTR)
    assert torch.equal(segment_person(alone, INTR, memory=memory), single)
    small = Intrinsics.kinect_v1(160)
    _, other = segment_person_in_stream(torch.zeros(small.height, small.width), small)
    assert torch.equal(segment_person(alone, INTR, memory=other), single)

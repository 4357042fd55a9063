"""Candidate pixels of the ray-caster: every pixel a capsule can hit lies in its row spans."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.runtime.capsule_pixels import (
    capsule_ends,
    segment_boxes,
    segment_row_spans,
    span_pairs,
)
from depthmocap.runtime.raycast import _cast, render_body, segment_geometry
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, rest_pose
from depthmocap.shared.procedural_motion import random_poses

INTR = Intrinsics(160, 120, 143.95, 143.95, 79.5, 59.5)


def _spans(q, body, intr):
    kin = forward_kinematics(q, body)
    geom = segment_geometry(body, q)
    rot, origin = geom.frames(kin)
    ends = capsule_ends(rot, origin, geom.basis[:, 2], geom.span, geom.scale)
    boxes = segment_boxes(*ends, intr)
    return (*segment_row_spans(*ends, intr, boxes), boxes, rot, origin, geom)


def _all_hits(rot, origin, geom, intr):
    """(P, H, W) bool: pixels whose ray meets each primitive, occluded or not."""
    P, H, W = geom.segment.shape[0], intr.height, intr.width
    first = torch.zeros(P, H, dtype=torch.long)
    pix, prim, col, row = span_pairs(first, torch.full_like(first, W), W)
    rays = torch.stack(
        [(col - intr.cx) / intr.fx, (row - intr.cy) / intr.fy, torch.ones(col.shape)], -1
    ).to(rot.dtype)
    t = _cast(rays, prim, rot, origin, geom)  # (B, N)
    return torch.isfinite(t).any(0).reshape(P, H, W)


def _covered(first, count, W):
    cols = torch.arange(W)
    return (cols >= first[..., None]) & (cols < (first + count)[..., None])  # (P, H, W)


@pytest.mark.parametrize("distance", [3.0, 0.6, 0.2])
def test_spans_hold_every_hit_of_random_poses(distance):
    # Random poses at 3 m, a body the camera nearly touches, and one reaching behind it.
    body = BodyShape.default(torch.float64)
    q = torch.as_tensor(random_poses(3, np.random.default_rng(int(distance * 10)), spread=1.0))
    q[:, 0:3] = torch.tensor([0.1, 0.2, distance], dtype=torch.float64)
    first, count, boxes, rot, origin, geom = _spans(q, body, INTR)
    hits = _all_hits(rot, origin, geom, INTR)
    assert hits.any()
    assert not bool((hits & ~_covered(first, count, INTR.width)).any())


def test_spans_are_much_tighter_than_boxes_for_a_diagonal_limb():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.0, 3.0), dtype=torch.float64)
    arm = sk.SEGMENT_NAMES.index("l_upper_arm")  # a segment's primitive has its index
    q[0, sk.DOF_NAMES.index("l_humerus_abd")] = math.radians(45)
    first, count, boxes, rot, origin, geom = _spans(q, body, INTR)
    box_area = float((boxes[arm, 1] - boxes[arm, 0]) * (boxes[arm, 3] - boxes[arm, 2]))
    hits = _all_hits(rot, origin, geom, INTR)[arm]
    assert int(hits.sum()) <= int(count[arm].sum()) < 0.8 * box_area
    assert not bool((hits & ~_covered(first, count, INTR.width)[arm]).any())


def test_span_pairs_golden():
    first = torch.tensor([[2, 0, 5], [0, 1, 0]])
    count = torch.tensor([[2, 0, 1], [0, 3, 0]])
    pix, prim, col, row = span_pairs(first, count, 10)
    assert col.tolist() == [2, 3, 5, 1, 2, 3]
    assert row.tolist() == [0, 0, 2, 1, 1, 1]
    assert prim.tolist() == [0, 0, 0, 1, 1, 1]
    assert pix.tolist() == [2, 3, 25, 11, 12, 13]


def test_render_with_spans_equals_casting_every_pixel():
    body = BodyShape.default(torch.float64)
    q = torch.as_tensor(random_poses(4, np.random.default_rng(3), spread=1.0))
    q[:, 0:3] = torch.tensor([-0.2, 0.1, 2.5], dtype=torch.float64)
    fast = render_body(q, body, INTR, details=False)
    full = render_body(q, body, INTR, box=False, details=False)
    assert torch.equal(fast.primitive, full.primitive) and torch.equal(fast.depth, full.depth)

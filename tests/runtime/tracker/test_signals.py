"""The tracker's fit signals (runtime.tracker.signals): limb visibility, the surface error."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker.signals import limb_visibility, surface_error_quantile
from depthmocap.runtime.tracker.tracker import expand_observation
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose
from depthmocap.shared.so3 import matrix_to_rotvec, rotvec_to_matrix

pytestmark = pytest.mark.usefixtures("one_thread")


class TestLimbVisibility:
    def test_front_and_profile(self):
        """About 1 for limbs in plain view; the far arm of a profile view is hidden (0)."""
        body, intr = BodyShape.default(torch.float64), Intrinsics.kinect_v1(160)
        q = rest_pose(1, (0.0, 0.1, 2.5), dtype=torch.float64)
        turn = rotvec_to_matrix(torch.tensor([[0.0, math.pi / 2, 0.0]], dtype=torch.float64))
        profile = q.clone()
        profile[:, 3:6] = matrix_to_rotvec(turn @ rotvec_to_matrix(q[:, 3:6]))
        both = torch.cat([q, profile])
        vis = limb_visibility(render_body(both, body, intr), intr, body)
        assert vis.shape == (2, 4)
        assert ((vis[0] > 0.8) & (vis[0] < 1.3)).all()
        assert vis[1, 0] > 0.8 and vis[1, 2] > 0.8  # near arm and leg
        assert vis[1, 1] < 0.05 and vis[1, 3] < 0.2  # far arm hidden, far leg mostly


class TestSurfaceErrorQuantile:
    def test_a_batch_of_views_of_one_frame_is_measured_as_separate_frames(
        self, make_pose, render_frame
    ):
        """The batched refits' observation (K stride-0 views of one frame) samples one frame's
        points for all K poses; a batch of K separate copies pads each pose's own: the
        same quantiles to the bit. Distinct frames keep their own points."""
        body = BodyShape.default(torch.float32)
        q = make_pose(torch.float32)
        obs = render_frame(q, body)
        poses = q.repeat(3, 1)
        poses[1, 2] += 0.05
        poses[2, 0] += 0.1
        render = render_body(poses, body, Intrinsics.kinect_v1(160), details=False)
        views = expand_observation(obs, 3)
        copies = dataclasses.replace(
            views, **{f.name: getattr(views, f.name).contiguous() for f in
                      dataclasses.fields(views) if f.name != "intr" and
                      getattr(views, f.name) is not None}
        )  # fmt: skip
        assert views.valid.stride(0) == 0 and copies.valid.stride(0) != 0
        shared = surface_error_quantile(views, render, body, 200)
        padded = surface_error_quantile(copies, render, body, 200)
        assert torch.equal(shared, padded)
        assert float(shared[0]) < float(shared[1]) < float(shared[2])
        alone = surface_error_quantile(obs, render_body(poses[2:], body, obs.intr), body, 200)
        assert torch.equal(alone, shared[2:])
        # Distinct frames: pose 0's frame empty, so its quantile is 0, the others' their own.
        copies.valid[0] = False
        mixed = surface_error_quantile(copies, render, body, 200)
        assert float(mixed[0]) == 0.0 and torch.equal(mixed[1:], shared[1:])

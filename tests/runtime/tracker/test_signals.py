"""The tracker's fit signals (runtime.tracker.signals): limb visibility."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker.signals import limb_visibility
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

"""The tracker's silhouette term (runtime.tracker.silhouette_term): rows for a spilled edge
and their Jacobian against finite differences of the projected point."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import TrackerConfig, silhouette_term
from depthmocap.runtime.tracker.gauss_newton import rows_jacobian
from depthmocap.runtime.tracker.silhouette_term import silhouette_rows
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, pose_update, segment_points_to_world

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}

pytestmark = pytest.mark.usefixtures("one_thread")


class TestSilhouetteRows:
    def test_jacobian_matches_finite_differences(self, monkeypatch, make_pose, render_frame):
        """The rows follow the projected point: sign on a spilled edge, then finite
        differences."""
        body = BodyShape.default(torch.float64)
        q = make_pose()
        shifted = q.clone()
        shifted[0, 0] += 0.04  # observed person 4 cm to the right: the left edge spills over
        obs = render_frame(shifted, body)
        render = render_body(q, body, obs.intr)
        monkeypatch.setattr(silhouette_term, "MAX_SILHOUETTE_PIXELS", 100000)
        cfg = TrackerConfig()
        rows = silhouette_rows(render, obs, cfg)
        assert len(rows) > 20 and bool((rows.residual < 0).all())
        jac = rows_jacobian(render.kin, rows)
        # Moving the body right (+x) must reduce the distance of the spilled left edge.
        assert float(jac[:, 0].mean()) < 0
        # The row is grad(dist) . d(pixel)/dq of the surface point: compare with finite
        # differences of the projected point, with the distance gradient at each row's pixel.
        intr, pts, kin = obs.intr, rows.points, render.kin
        u = torch.round(intr.fx * pts[:, 0] / pts[:, 2] + intr.cx).long()
        v = torch.round(intr.fy * pts[:, 1] / pts[:, 2] + intr.cy).long()
        grad = obs.distance_grad[0, v, u]
        local = ((pts - kin.origins[0, rows.segment])[:, None] @ kin.rotations[0, rows.segment])[
            :, 0
        ]

        def pixels(dq):
            p = segment_points_to_world(
                forward_kinematics(pose_update(q, dq), body), local[None], rows.segment
            )[0]
            return torch.stack([intr.fx * p[:, 0] / p[:, 2], intr.fy * p[:, 1] / p[:, 2]], -1)

        eps = 1e-6
        for dof in (0, 1, 2, 5, D["lower_back_y"], D["l_humerus_abd"]):
            dq = torch.zeros(1, 34, dtype=torch.float64)
            dq[0, dof] = eps
            fd = ((pixels(dq) - pixels(-dq)) * grad).sum(-1) / (2 * eps)
            assert torch.allclose(jac[:, dof], fd, atol=1e-4, rtol=1e-4), sk.DOF_NAMES[dof]


def test_the_compiled_term_gives_the_torch_rows_bit_for_bit(
    assert_same_rows, monkeypatch, off_truth_batch
):
    """runtime.tracker.silhouette_kernel (one compiled call, CPU float32) against the torch
    code it replaces, on a batch of poses spilling over the observed silhouette by different
    amounts, thinned and not: the same rows to the bit."""
    pytest.importorskip("depthmocap.runtime.tracker.silhouette_kernel")
    _, obs, _, render = off_truth_batch([{"root_tx": 0.04}, {"l_humerus_abd": 0.4}])
    cfg = TrackerConfig()
    for cap in (60, 100000):
        monkeypatch.setattr(silhouette_term, "MAX_SILHOUETTE_PIXELS", cap)
        got = silhouette_rows(render, obs, cfg)
        with monkeypatch.context() as m:  # the torch code (its sampling still compiled)
            m.setattr(silhouette_term, "compiled_float32", lambda name, *t: None)
            want = silhouette_rows(render, obs, cfg)
        assert len(want) > 20
        assert_same_rows(got, want, cap)

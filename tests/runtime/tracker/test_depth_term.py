"""The tracker's depth term (runtime.tracker.depth_term): its rows' Jacobian against finite
differences of the rendered depth."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import TrackerConfig, depth_term
from depthmocap.runtime.tracker.depth_term import depth_rows
from depthmocap.runtime.tracker.gauss_newton import rows_jacobian
from depthmocap.runtime.tracker.regions import classify, rendered_points
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import pose_update

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}

pytestmark = pytest.mark.usefixtures("one_thread")


class TestDepthRows:
    def test_jacobian_matches_finite_differences(self, monkeypatch, make_pose, render_frame):
        """The rows match finite differences of the rendering at interior pixels."""
        body = BodyShape.default(torch.float64)
        q = make_pose()
        obs = render_frame(q, body)
        monkeypatch.setattr(depth_term, "MAX_DEPTH_PIXELS", 100000)
        monkeypatch.setattr(depth_term, "MIN_COSINE", 0.5)
        cfg = TrackerConfig()
        render = render_body(q, body, obs.intr)
        regions = classify(render, obs, 0.08, True)
        # Interior pixels: the same segment in the 5x5 neighbourhood (no edge within reach).
        seg = render.segment[0]
        pad = torch.nn.functional.pad(seg, (2, 2, 2, 2), value=-1)
        same = torch.stack(
            [
                pad[i : i + seg.shape[0], j : j + seg.shape[1]] == seg
                for i in range(5)
                for j in range(5)
            ]
        ).all(0)
        regions.good = regions.good & same[None]
        rows = depth_rows(render, obs, regions, cfg)
        keep = rows.weight > 0
        jac = rows_jacobian(render.kin, rows)[keep]
        # Rows are d(depth)/dq scaled by |cos| (residual along the normal): undo the scaling.
        idx = regions.good.nonzero()[keep]
        pts, _ = rendered_points(render, idx, obs.intr)
        normal = render.normals[idx[:, 0], idx[:, 1], idx[:, 2]]
        cos = ((normal * pts).sum(-1) / pts.norm(dim=-1)).abs()
        eps = 1e-6
        for dof in (0, 2, 4, D["lower_back_y"], D["l_humerus_abd"], D["r_femur_flex"], D["head_y"]):
            dq = torch.zeros(1, 34, dtype=torch.float64)
            dq[0, dof] = eps
            plus = render_body(pose_update(q, dq), body, obs.intr).depth
            minus = render_body(pose_update(q, -dq), body, obs.intr).depth
            fd = (plus - minus)[idx[:, 0], idx[:, 1], idx[:, 2]] / (2 * eps)
            assert torch.allclose(jac[:, dof] / cos, fd, atol=1e-4, rtol=1e-4), sk.DOF_NAMES[dof]


def test_the_compiled_term_gives_the_torch_rows_bit_for_bit(
    assert_same_rows, monkeypatch, off_truth_batch
):
    """runtime.tracker.depth_kernel (the term and its surface normals in one compiled call,
    CPU float32) against the torch code it replaces, on a batch of poses off the truth by
    different amounts, thinned and not: the same rows to the bit."""
    pytest.importorskip("depthmocap.runtime.tracker.depth_kernel")
    changes = [{"root_tx": 0.02}, {"l_humerus_abd": 0.3}]
    _, obs, _, render = off_truth_batch(changes, details=False)
    regions = classify(render, obs, 0.08, True)
    cfg = TrackerConfig()
    for cap in (150, 100000):
        monkeypatch.setattr(depth_term, "MAX_DEPTH_PIXELS", cap)
        got = depth_term.depth_rows(render, obs, regions, cfg)
        with monkeypatch.context() as m:  # the torch code (its sampling still compiled)
            m.setattr(depth_term, "compiled_float32", lambda name, *t: None)
            want = depth_term.depth_rows(render, obs, regions, cfg)
        assert len(want) > 100
        assert_same_rows(got, want, cap)

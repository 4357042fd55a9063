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


def _torso_labelled(obs, render, parts=("forearm",)):
    """The observation with labels (segments) that call every pixel the model renders as an
    arm's ``parts`` the chest, and the rest what the model renders there; the segments of
    the forearms."""
    labels = render.segment.clone()
    chest = [sk.SEGMENT_NAMES.index(f"{side}_{p}") for side in "lr" for p in parts]
    labels[torch.isin(labels, torch.tensor(chest))] = sk.SEGMENT_NAMES.index("chest")
    obs.labels = labels
    return obs, [sk.SEGMENT_NAMES.index("l_forearm"), sk.SEGMENT_NAMES.index("r_forearm")]


def test_a_limb_on_torso_labels_is_pushed_behind(monkeypatch, off_truth_batch):
    """Where the forest says chest, a rendered forearm's depth rows aim behind the observed
    surface by HIDDEN_BY_LABEL_M; every other row is unchanged, and without labels or with
    the push off nothing changes (torch code; the limb-label clearance off here, below)."""
    _, obs, _, render = off_truth_batch([{"l_humerus_abd": 0.3}], details=False)
    regions = classify(render, obs, 0.08, True)
    cfg = TrackerConfig()
    monkeypatch.setattr(depth_term, "compiled_float32", lambda name, *t: None)
    monkeypatch.setattr(depth_term, "MAX_DEPTH_PIXELS", 100000)
    monkeypatch.setattr(depth_term, "HIDDEN_CLEAR_PX", 0)
    plain = depth_term.depth_rows(render, obs, regions, cfg)
    obs, forearms = _torso_labelled(obs, render)
    pushed = depth_term.depth_rows(render, obs, regions, cfg)
    on = torch.isin(pushed.segment, torch.tensor(forearms))
    assert int(on.sum()) > 10
    # residual = (diff + push) |cos|, |cos| read back from the row: direction = -n / |d|.
    ray = pushed.points.norm(dim=-1) / pushed.points[:, 2]
    normal = -pushed.direction * ray[:, None]
    cos = (normal * pushed.points).sum(-1).abs() / pushed.points.norm(dim=-1)
    push = depth_term.HIDDEN_BY_LABEL_M * cos[on]
    torch.testing.assert_close(pushed.residual[on] - plain.residual[on], push)
    assert torch.equal(pushed.residual[~on], plain.residual[~on])
    monkeypatch.setattr(depth_term, "HIDDEN_BY_LABEL_M", 0.0)
    assert torch.equal(depth_term.depth_rows(render, obs, regions, cfg).residual, plain.residual)


def test_no_push_next_to_limb_labels(monkeypatch, off_truth_batch):
    """With the clearance, only rows with no limb label within HIDDEN_CLEAR_PX pixels are
    pushed: none where only the forearms are called chest (the upper arms' labels are next
    to them), some once the whole arms are."""
    _, obs, _, render = off_truth_batch([{"l_humerus_abd": 0.3}], details=False)
    regions = classify(render, obs, 0.08, True)
    cfg = TrackerConfig()
    monkeypatch.setattr(depth_term, "compiled_float32", lambda name, *t: None)
    monkeypatch.setattr(depth_term, "MAX_DEPTH_PIXELS", 100000)
    monkeypatch.setattr(depth_term, "HIDDEN_CLEAR_PX", 2)
    plain = depth_term.depth_rows(render, obs, regions, cfg)
    obs, forearms = _torso_labelled(obs, render, ("upper_arm", "forearm"))
    whole = depth_term.depth_rows(render, obs, regions, cfg)
    changed = whole.residual != plain.residual
    limb = (obs.labels >= sk.FIRST_LIMB_SEGMENT).double()[:, None]
    near = torch.nn.functional.max_pool2d(limb, 5, stride=1, padding=2)[:, 0] > 0
    assert int(changed.sum()) > 10
    assert bool(torch.isin(whole.segment[changed], torch.tensor(forearms + [7, 8])).all())
    b, v, u = _pixels_of(whole, obs)
    assert not bool(near[b, v, u][changed].any())
    obs, _ = _torso_labelled(obs, render)  # the upper arms labelled again: ...
    obs.labels[render.segment == 7] = 7
    obs.labels[render.segment == 8] = 8
    assert int(
        (depth_term.depth_rows(render, obs, regions, cfg).residual != plain.residual).sum()
    ) < int(changed.sum())


def _pixels_of(rows, obs):
    """The (batch, row, column) working pixel of each row's surface point."""
    x, y, z = rows.points.unbind(-1)
    u = torch.round(obs.intr.fx * x / z + obs.intr.cx).long()
    v = torch.round(obs.intr.fy * y / z + obs.intr.cy).long()
    return rows.batch, v, u


def test_the_compiled_push_gives_the_torch_rows_bit_for_bit(
    assert_same_rows, monkeypatch, off_truth_batch
):
    """The same with the torso labels, compiled (float32) against torch."""
    pytest.importorskip("depthmocap.runtime.tracker.depth_kernel")
    _, obs, _, render = off_truth_batch([{"l_humerus_abd": 0.3}], details=False)
    regions = classify(render, obs, 0.08, True)
    cfg = TrackerConfig()
    plain = depth_term.depth_rows(render, obs, regions, cfg)
    obs, _ = _torso_labelled(obs, render, ("upper_arm", "forearm"))
    got = depth_term.depth_rows(render, obs, regions, cfg)
    assert bool((got.residual != plain.residual).any())  # some rows pushed
    with monkeypatch.context() as m:
        m.setattr(depth_term, "compiled_float32", lambda name, *t: None)
        want = depth_term.depth_rows(render, obs, regions, cfg)
    assert_same_rows(got, want)

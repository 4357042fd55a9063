"""Static surfaces behind the tracked body (runtime.hybrid.behind_model): the depth behind the
nearest axis (golden), a rendered body with a still "chair" behind its legs and a moving one,
no track, the settings, the frame's dropped pixels and the preset that switches it on."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.frame import Frame, FrameError
from depthmocap.runtime.hybrid.behind_model import (
    BehindModelConfig,
    StaticBehindMask,
    depth_behind_axes,
)
from depthmocap.runtime.hybrid.config import HybridConfig
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import ConfigError, config_from_dict
from depthmocap.shared.kinematics import forward_kinematics, rest_pose

INTR = Intrinsics.kinect_v1(160)


def test_depth_behind_axes_golden():
    start = torch.tensor([[0.0, 0.0, 2.0], [0.5, 0.0, 2.0]], dtype=torch.float64)
    end = torch.tensor([[0.0, 0.5, 2.0], [0.5, 0.5, 2.0]], dtype=torch.float64)
    points = torch.tensor(
        [[0.1, 0.2, 2.3], [0.05, 0.2, 1.95], [0.45, 0.9, 2.1], [0.0, -0.1, 2.0]],
        dtype=torch.float64,
    )
    # Nearest axes: the first (0.1 away), the first, the second's end (0.5, 0.5), the first's
    # start; behind = the point's z minus that axis point's.
    expected = torch.tensor([0.3, -0.05, 0.1, 0.0], dtype=torch.float64)
    torch.testing.assert_close(depth_behind_axes(points, start, end), expected)


def _scene():
    """A rendered standing body 2.5 m away and a "chair": a block of pixels below its hips,
    between and beside the legs, 0.4 m behind them (m)."""
    body = BodyShape.default(torch.float32)
    q = rest_pose(1, root_position=(0.0, 0.0, 2.5))
    depth = render_body(q, body, INTR).depth[0]
    rows, cols = torch.nonzero(depth > 0, as_tuple=True)
    v0 = int(rows.float().quantile(0.55))
    u0, u1 = int(cols.min()) - 6, int(cols.max()) + 6
    chair = torch.zeros_like(depth, dtype=torch.bool)
    chair[v0 : v0 + 12, u0:u1] = True
    chair &= depth == 0  # only where the body does not hide it
    return body, q, depth, chair


def _frames(depth, chair, n, chair_z):
    for i in range(n):
        d = depth.clone()
        d[chair] = chair_z(i)
        yield d, d > 0


@pytest.mark.parametrize("compiled", [True, False])
def test_a_still_surface_behind_the_legs_is_dropped_the_body_never(compiled):
    body, q, depth, chair = _scene()
    assert chair.sum() > 40
    kin = forward_kinematics(q, body)
    memory = StaticBehindMask(BehindModelConfig(behind_m=0.12, static_frames=3), compiled)
    for i, (d, mask) in enumerate(_frames(depth, chair, 6, lambda i: 2.9)):
        drop = memory.update(d, mask, kin, INTR)
        assert not (drop & (depth > 0)).any()  # no body pixel, ever
        # Counted from the second frame on (the first has no depth before it): dropped at
        # the fourth.
        assert bool(drop[chair].all()) == (i >= 3), i
    # A surface as far behind that moves 5 cm a frame is never dropped.
    memory.reset()
    for d, mask in _frames(depth, chair, 6, lambda i: 2.9 + 0.05 * i):
        assert not memory.update(d, mask, kin, INTR).any()
    # Without a track nothing is counted: the memory starts over.
    memory.reset()
    for i, (d, mask) in enumerate(_frames(depth, chair, 8, lambda i: 2.9)):
        drop = memory.update(d, mask, None if i == 3 else kin, INTR)
        assert not drop.any() if i <= 6 else bool(drop[chair].all()), i


def test_the_compiled_update_decides_as_the_torch_one():
    pytest.importorskip("numba")
    body, q, depth, chair = _scene()
    gen = torch.Generator().manual_seed(0)
    kin = forward_kinematics(q, body)
    memories = [StaticBehindMask(BehindModelConfig(0.05, 2), c) for c in (True, False)]
    for i in range(5):
        # Noisy depth everywhere, so that some pixels pass the stillness test and some not.
        d = depth.clone()
        d[chair] = 2.9
        d = torch.where(d > 0, d + 0.02 * torch.randn(d.shape, generator=gen), d)
        drops = [m.update(d, d > 0, kin, INTR) for m in memories]
        assert torch.equal(drops[0], drops[1]), i
        assert torch.equal(memories[0]._count, memories[1]._count), i
    assert drops[0].any()


@pytest.mark.parametrize(
    "bad",
    [{"behind_m": 0.0}, {"behind_m": math.nan}, {"static_frames": 0}, {"static_tol_m": -0.01}],
)
def test_bad_settings_are_refused(bad):
    with pytest.raises(ConfigError, match="behind_model"):
        BehindModelConfig(**bad)


def test_the_frame_drops_pixels_from_its_mask_and_labels():
    depth = torch.full((4, 5), 2.0)
    frame = Frame(0, 0.0, depth, depth > 0, Intrinsics(5, 4, 5.0, 5.0, 2.0, 1.5))

    def source(f):
        return torch.full((4, 5), 3)

    frame.labels(source)
    drop = torch.zeros(4, 5, dtype=torch.bool)
    drop[1, 2] = True
    frame.drop_pixels(drop)
    assert not frame.mask[1, 2] and int(frame.mask.sum()) == 19
    assert int(frame.labels(source)[1, 2]) == 0 and int(frame.labels(source)[0, 0]) == 3
    tracker = Tracker(BodyShape.default(torch.float32), frame.intrinsics)
    frame.observation(tracker)
    with pytest.raises(FrameError, match="after an observation"):
        frame.drop_pixels(drop)


def test_the_setting_loads_from_a_preset_and_is_shipped_on():
    assert HybridConfig().behind_model == BehindModelConfig(behind_m=0.12, static_frames=5)
    cfg = config_from_dict(HybridConfig, {"behind_model": {"behind_m": 0.3}})
    assert cfg.behind_model == BehindModelConfig(behind_m=0.3)
    assert config_from_dict(HybridConfig, {"behind_model": None}).behind_model is None


def test_the_memory_follows_the_input_s_device(device):
    """On a GPU the torch code runs where the frame is (the compiled loop is for the CPU)."""
    body, q, depth, chair = _scene()
    kin = forward_kinematics(q.to(device), body.to(device=device))
    memory = StaticBehindMask(BehindModelConfig(behind_m=0.12, static_frames=1), compiled=False)
    d = torch.where(chair, torch.full_like(depth, 2.9), depth).to(device)
    assert not memory.update(d, d > 0, kin, INTR).any()
    drop = memory.update(d, d > 0, kin, INTR)
    assert drop.device == d.device and bool(drop[chair.to(device)].all())

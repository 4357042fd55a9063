"""What optional parts of the tracker step cost, as ratios against a step timed in the same run.

These machines' speed drifts by tens of percent within minutes, so an absolute time of a small
addition says little; a ratio against the step it belongs to, measured alongside, does.
"""

from __future__ import annotations

from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import rest_pose

from .timing import median_ms
from .tracker import benchmark_tracker

__all__ = ["collision_cost", "joint_support_cost"]


def collision_cost(device: str, rounds: int = 2, frames: int = 60) -> tuple[str, float, str]:
    """The tracker step with the collision term (the hybrid preset's) against without it, on
    the walk at 2.5 m, alternated ``rounds`` times (this host's speed drifts): (what, ms,
    note with the ratio)."""
    from depthmocap.runtime.tracker import TrackerConfig

    cfg = TrackerConfig(use_collision=True)
    with_term, without = [], []
    for _ in range(rounds):
        without.append(benchmark_tracker(device=device, frames=frames)["ms_per_frame"])
        with_term.append(benchmark_tracker(device=device, frames=frames, cfg=cfg)["ms_per_frame"])
    ms, base = min(with_term), min(without)
    return (
        "tracker step with the collision term, person at 2.5 m",
        ms,
        f"{ms / base:.3f} of the step without it ({base:.1f} ms; best of {rounds}, alternated)",
    )


def joint_support_cost(device: str, repeats: int = 20) -> tuple[str, float, str]:
    """The observed-joint flags (:func:`runtime.tracker.joint_support.joint_support_cm2`, with
    labels) on a 320x240 frame of the default body at 3 m, against a tracker step on the same
    frame, timed in the same run: (what, ms, note with the ratio)."""
    from depthmocap.runtime.raycast import render_body
    from depthmocap.runtime.tracker import Tracker
    from depthmocap.runtime.tracker.joint_support import joint_support_cm2
    from depthmocap.runtime.tracker.observation import observe
    from depthmocap.runtime.tracker.regions import classify
    from depthmocap.runtime.tracker.tracker import SILHOUETTE_MAX_PX
    from depthmocap.shared.camera import Intrinsics

    intr, body = Intrinsics.kinect_v1(320), BodyShape.default().to(device=device)
    q = rest_pose(1, root_position=(0.0, 0.1, 3.0)).to(device)
    render = render_body(q, body, intr)
    obs = observe(render.depth, render.mask, intr, 1, SILHOUETTE_MAX_PX)
    regions = classify(render, obs, 0.08, True)
    tracker, depth = Tracker(body, intr, device=device), render.depth[0]
    ms = median_ms(
        lambda: joint_support_cm2(render, regions, intr, render.segment), repeats, device=device
    )
    step = median_ms(lambda: tracker.step(depth, depth > 0, q[0]), repeats, device=device)
    return (
        f"observed-joint flags, {int(regions.good.sum())} pixels at 3 m",
        ms,
        f"{ms / step:.3f} of a tracker step on the same frame ({step:.1f} ms, which includes it)",
    )

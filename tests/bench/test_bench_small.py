"""The timer every benchmark uses (bench.timing), the kinematics and segmentation figures, and
the synthetic forest frame."""

from __future__ import annotations

import math

import torch
from depthmocap.bench.kinematics import kinematics_rows, random_poses
from depthmocap.bench.scenes import person_frame
from depthmocap.bench.segmentation import benchmark_segmentation
from depthmocap.bench.timing import alternating_median_ms, median_ms, wall_ms
from depthmocap.shared import skeleton as sk


def test_median_ms_warms_up_then_takes_the_median():
    calls = []
    ms = median_ms(lambda: calls.append(1), repeats=5, warmup=2)
    assert len(calls) == 7 and 0 <= ms < 50
    assert wall_ms(lambda: None) >= 0


def test_alternating_median_ms_takes_turns():
    calls = []
    ms = alternating_median_ms(
        {"a": lambda: calls.append("a"), "b": lambda: calls.append("b")}, repeats=4, warmup=1
    )
    assert (
        calls == ["a", "b"] * 5 and set(ms) == {"a", "b"} and all(0 <= t < 50 for t in ms.values())
    )


def test_kinematics_rows_compare_against_autograd():
    rows = kinematics_rows(20, "cpu")
    assert [r[0] for r in rows][:2] == ["FK, 20 poses", "FK + 16-joint Jacobian, 20 poses"]
    assert all(ms > 0 for _, ms, _ in rows) and "faster" in rows[2][2]
    q = random_poses(4, torch.float64, "cpu")
    half = 0.5 * torch.as_tensor(sk.DOF_LIMITS[6:], dtype=torch.float64)
    assert ((q[:, 6:] >= half[:, 0]) & (q[:, 6:] <= half[:, 1])).all()


def test_segmentation_benchmark_reports_positive_times():
    times = benchmark_segmentation(frames=2, stride=1)
    assert set(times) == {"segment_person_ms", "segment_person_batch_ms"}
    assert all(math.isfinite(t) and t > 0 for t in times.values())


def test_person_frame_is_a_person_at_about_2_5_m():
    depth, mask = person_frame()
    assert depth.shape == (240, 320) and (depth[mask] > 2).all() and (depth[~mask] == 0).all()
    assert 5000 < mask.sum() < 9000

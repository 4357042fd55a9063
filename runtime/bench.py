"""``make bench``: speed figures of the runtime's hot paths, printed, never asserted.

Each figure is the median over repeats after a warm-up; ratios compare against a baseline
measured in the same run, because these machines are noisy.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from shared.body import BodyShape
from shared.kinematics import (
    forward_kinematics,
    named_joint_positions,
    point_jacobian,
    pose_update,
    rest_pose,
)
from shared.skeleton import DOF_LIMITS, JOINT_FRACTION, JOINT_SEGMENT

__all__ = [
    "time_call",
    "bench_kinematics",
    "bench_tracker",
    "collision_cost",
    "joint_support_cost",
    "bench_recordings",
    "main",
]


def time_call(fn: Callable[[], object], repeats: int = 20, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` in milliseconds (CUDA synchronized)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def _random_poses(batch: int, dtype, device) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    q = rest_pose(batch, dtype=dtype)
    lim = torch.as_tensor(DOF_LIMITS[6:], dtype=dtype)
    q[:, 6:] = 0.5 * (
        lim[:, 0] + torch.rand(batch, 28, generator=g, dtype=dtype) * (lim[:, 1] - lim[:, 0])
    )
    return q.to(device)


def bench_kinematics(batch: int, device: str, dtype=torch.float32) -> list[tuple[str, float, str]]:
    """FK and Jacobian timings for ``batch`` poses; rows of (what, ms, note)."""
    body = BodyShape.default(dtype, device)
    q = _random_poses(batch, dtype, device)
    seg = torch.as_tensor(JOINT_SEGMENT, device=device)

    def fk():
        return forward_kinematics(q, body)

    def fk_jac():
        kin = forward_kinematics(q, body)
        p = named_joint_positions(kin)
        return point_jacobian(kin, p, seg)

    # Baseline: the same Jacobian by reverse-mode autograd through FK (what a naive
    # implementation would do), on a smaller batch and scaled up.
    small = max(1, batch // 10)
    qs = q[:small]

    def autograd_jac():
        def f(dq):
            return named_joint_positions(forward_kinematics(pose_update(qs, dq), body)).sum(0)

        return torch.autograd.functional.jacobian(f, torch.zeros_like(qs), vectorize=True)

    t_fk = time_call(fk)
    t_jac = time_call(fk_jac)
    t_auto = time_call(autograd_jac, repeats=5) * batch / small
    # One tracker-sized call: a single pose and 5,000 surface points.
    kin1 = forward_kinematics(q[:1], body)
    pts = torch.randn(1, 5000, 3, dtype=dtype, device=device) * 0.1 + q[:1, None, :3]
    pseg = torch.randint(0, 15, (5000,), device=device)
    t_track = time_call(lambda: point_jacobian(kin1, pts, pseg))
    _ = JOINT_FRACTION
    return [
        (f"FK, {batch} poses", t_fk, "target < 5 ms on 2 CPU cores"),
        (f"FK + 16-joint Jacobian, {batch} poses", t_jac, ""),
        (
            f"autograd Jacobian baseline, {batch} poses",
            t_auto,
            f"analytic is {t_auto / t_jac:.1f}x faster",
        ),
        ("Jacobian of 5,000 surface points, 1 pose", t_track, "per tracker iteration"),
    ]


def bench_tracker(device: str) -> list[tuple[str, float, str]]:
    """Tracker frame time and ray-cast time; rows of (what, ms, note)."""
    from runtime.tracker import benchmark_tracker

    rows = []
    for distance in (2.5, 3.5):
        r = benchmark_tracker(device=device, frames=60, distance_m=distance)
        at = (
            f"person at {distance} m: {r['working_pixels']:.0f} pixels at "
            f"{r['working_width']:.0f} px wide"
        )
        rows += [
            (
                f"tracker step (Gauss-Newton, all terms), {at}",
                r["ms_per_frame"],
                f"{r['frames_per_s']:.1f} frames/s, {r['iterations_mean']:.1f} iterations, "
                f"joint error {r['joint_error_mm']:.1f} mm; target >= 30 frames/s",
            ),
            (f"ray-cast of the body, {at}", r["raycast_ms"], "one render per iteration"),
        ]
    rows.append(collision_cost(device))
    rows.append(joint_support_cost(device))
    return rows


def joint_support_cost(device: str, repeats: int = 20) -> tuple[str, float, str]:
    """The observed-joint flags (:func:`runtime.tracker.joint_support.joint_support_cm2`, with
    labels) on a 320x240 frame of the default body at 3 m, against a tracker step on the same
    frame, timed in the same run: (what, ms, note with the ratio)."""
    from runtime.raycast import render_body
    from runtime.tracker import Tracker
    from runtime.tracker.joint_support import joint_support_cm2
    from runtime.tracker.observation import observe
    from runtime.tracker.regions import classify
    from shared.camera import Intrinsics

    intr, body = Intrinsics.kinect_v1(320), BodyShape.default().to(device=device)
    q = rest_pose(1, root_position=(0.0, 0.1, 3.0)).to(device)
    render = render_body(q, body, intr)
    obs = observe(render.depth, render.mask, intr, 1, 10.0)
    regions = classify(render, obs, 0.08, True)
    tracker, depth = Tracker(body, intr, device=device), render.depth[0]
    ms = time_call(lambda: joint_support_cm2(render, regions, intr, render.segment), repeats)
    step = time_call(lambda: tracker.step(depth, depth > 0, q[0]), repeats)
    return (
        f"observed-joint flags, {int(regions.good.sum())} pixels at 3 m",
        ms,
        f"{ms / step:.3f} of a tracker step on the same frame ({step:.1f} ms, which includes it)",
    )


def collision_cost(device: str, rounds: int = 2, frames: int = 60) -> tuple[str, float, str]:
    """The tracker step with the collision term (the hybrid preset's) against without it, on
    the walk at 2.5 m, alternated ``rounds`` times (this host's speed drifts): (what, ms,
    note with the ratio)."""
    from runtime.tracker import TrackerConfig, benchmark_tracker

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


def bench_recordings(folder: Path, device: str) -> list[tuple[str, float, str]]:
    """Tracker frame time on each recording with ground truth in ``folder``."""
    from runtime.tracker.benchmark import benchmark_recording

    rows = []
    for rec in sorted(d for d in folder.iterdir() if (d / "groundtruth.npz").is_file()):
        r = benchmark_recording(rec, device=device)
        rows.append(
            (
                f"tracker step, {rec.name}",
                r["ms_per_frame"],
                f"{1e3 / r['ms_per_frame']:.1f} frames/s, {r['iterations_mean']:.1f} "
                f"iterations, {r['working_pixels']:.0f} working pixels",
            )
        )
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000, help="poses per FK call")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda", "all"])
    parser.add_argument(
        "--recordings",
        type=Path,
        help="also time the tracker on each recording with ground truth in this folder "
        "(make dev-recordings: anny bodies and sensor noise)",
    )
    args = parser.parse_args(argv)
    if args.recordings is not None and not args.recordings.is_dir():
        parser.error(f"--recordings {args.recordings}: no such folder")
    torch.set_num_threads(args.threads)
    devices = ["cpu", "cuda"] if args.device == "all" else [args.device]
    devices = [d for d in devices if d == "cpu" or torch.cuda.is_available()]
    print(f"torch {torch.__version__}, {args.threads} CPU threads")
    for dev in devices:
        name = torch.cuda.get_device_name() if dev == "cuda" else "CPU"
        print(f"\n== kinematics on {name} ==")
        for what, ms, note in bench_kinematics(args.batch, dev):
            print(f"  {what:<45s} {ms:9.3f} ms  {note}")
        if dev == "cpu":
            from runtime.segmentation_benchmark import benchmark_segmentation

            seg = benchmark_segmentation()
            print("\n== person segmentation (CPU, numpy/OpenCV), 320x240 demo frames ==")
            print(f"  {'segment_person, one frame':<45s} {seg['segment_person_ms']:9.3f} ms")
            from runtime.forest.benchmark import benchmark_forest

            fr = benchmark_forest(threads=args.threads)
            if fr:
                print(
                    f"\n== forest inference (models/forest.npz: {fr['trees']:.0f} trees, depth "
                    f"{fr['depth']:.0f}), {fr['pixels']:.0f} person pixels of a 320x240 frame =="
                )
                for key, what in (
                    ("torch_cpu_ms", "torch CPU, every person pixel"),
                    ("torch_cpu_stride2_ms", "torch CPU, every 2nd pixel (detector)"),
                    ("onnxruntime_ms", "onnxruntime CPU, every person pixel"),
                ):
                    if key in fr:
                        print(f"  {what:<45s} {fr[key]:9.3f} ms  target <= 10 ms")
                if "torch_cpu_smoothed_ms" in fr:
                    ratio = fr["torch_cpu_smoothed_ms"] / fr["torch_cpu_ms"]
                    print(
                        f"  {'torch CPU, 5x5 smoothed (detector, hybrid)':<45s} "
                        f"{fr['torch_cpu_smoothed_ms']:9.3f} ms  {ratio:.2f} of the raw forest's"
                    )
        print(f"\n== tracker on {name} (cylinder-model walk, 320x240 in; working resolution ==")
        print("   and window from the person's size)")
        for what, ms, note in bench_tracker(dev):
            print(f"  {what:<45s} {ms:9.3f} ms  {note}")
        if args.recordings is not None:
            where = f"recordings in {args.recordings}"
            print(f"\n== tracker on {name}, {where} (ground-truth start) ==")
            for what, ms, note in bench_recordings(args.recordings, dev):
                print(f"  {what:<45s} {ms:9.3f} ms  {note}")


if __name__ == "__main__":
    main()

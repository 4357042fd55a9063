"""``python -m depthmocap.bench.profile_hybrid``: where the whole hybrid's time goes on one
device, by torch operator, with the counts that bound a GPU run (kernel launches and host
syncs per frame). A diagnostic printed for a person, never asserted; ``runtime-bench`` gives
the figures to report.
"""

from __future__ import annotations

import argparse
import itertools

import torch
from depthmocap.runtime.api import Tracker
from depthmocap.runtime.streams import open_stream

__all__ = ["main", "profile_hybrid"]

# CUDA runtime calls that make the host wait for the device, or launch work on it.
_SYNC_CALLS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize")
_COPY_CALLS = ("cudaMemcpyAsync", "cudaMemcpy")
_LAUNCH_CALLS = ("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernelEx")


def profile_hybrid(source: str, device: str, frames: int, warmup: int = 5):
    """Profile ``frames`` frames of the shipped hybrid on ``source`` after ``warmup`` frames.

    Returns:
        the profiler's averaged events (``torch.autograd.profiler_util.EventList``).
    """
    tracker = Tracker(device=device)
    activities = [torch.profiler.ProfilerActivity.CPU]
    if tracker.device.startswith("cuda"):
        activities.append(torch.profiler.ProfilerActivity.CUDA)
    with open_stream(source) as stream:
        frames_iter = iter(stream)
        for frame in itertools.islice(frames_iter, warmup):
            tracker.track(frame)
        with torch.profiler.profile(activities=activities) as prof:
            for frame in itertools.islice(frames_iter, frames):
                tracker.track(frame)
    return prof.key_averages()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="demo", help="any runtime-track --input")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rows", type=int, default=25)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    events = profile_hybrid(args.source, args.device, args.frames)
    per_frame = {e.key: e.count / args.frames for e in events}
    for label, names in (("host syncs", _SYNC_CALLS), ("copies", _COPY_CALLS),
                         ("kernel launches", _LAUNCH_CALLS)):  # fmt: skip
        print(f"{label} per frame: {sum(per_frame.get(n, 0.0) for n in names):.0f}")
    sort = "self_cuda_time_total" if args.device == "cuda" else "self_cpu_time_total"
    print(events.table(sort_by=sort, row_limit=args.rows))
    if args.device == "cuda":
        print(events.table(sort_by="self_cpu_time_total", row_limit=args.rows))


if __name__ == "__main__":
    main()

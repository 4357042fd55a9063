"""Speed of :func:`runtime.segmentation.segment_person` on the built-in demo (``make bench``).

The demo needs no data: a person with the floor in view and Kinect-like noise, 320 x 240.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from .segmentation import SegmentationConfig, segment_person
from .streams.base import FrameRange
from .streams.demo import open_demo_stream

__all__ = ["benchmark_segmentation"]


def benchmark_segmentation(frames: int = 30, stride: int = 6) -> dict[str, float]:
    """Milliseconds per frame of person segmentation on ``frames`` demo frames.

    Frames are taken every ``stride``-th frame of the demo (different motions); each figure
    is the median over the frames after a warm-up, so that a loaded machine's hiccups count
    less. Returns ``{"segment_person_ms": ..., "segment_person_batch_ms": ...}``: one frame
    per call, and all frames in one batched call (per frame).
    """
    stream = open_demo_stream(frame_range=FrameRange(0, max(frames, 1) * stride))
    depth = [
        torch.from_numpy(f.depth_mm.astype(np.float32) * 1e-3)
        for f in stream
        if f.index % stride == 0
    ]
    intr = stream.intrinsics
    cfg = SegmentationConfig()
    segment_person(depth[0], intr, cfg)  # warm-up (imports, allocator)
    times = []
    for d in depth:
        t0 = time.perf_counter()
        segment_person(d, intr, cfg)
        times.append((time.perf_counter() - t0) * 1e3)
    batch = torch.stack(depth)
    t0 = time.perf_counter()
    segment_person(batch, intr, cfg)
    batch_ms = (time.perf_counter() - t0) * 1e3 / len(depth)
    return {"segment_person_ms": float(np.median(times)), "segment_person_batch_ms": batch_ms}


if __name__ == "__main__":
    torch.set_num_threads(1)
    for name, ms in benchmark_segmentation().items():
        print(f"{name:<28s} {ms:8.3f} ms/frame")

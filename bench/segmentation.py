"""Speed of :func:`runtime.segmentation.segment_person` on the built-in demo stream.

The demo needs no data: a person with the floor in view and Kinect-like noise, 320x240.
Different frames (different motions) are timed rather than one frame repeated, because the
floor fit's cost depends on what is in view.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from depthmocap.runtime.segmentation import SegmentationConfig, segment_person
from depthmocap.runtime.streams.base import FrameRange
from depthmocap.runtime.streams.demo import open_demo_stream

from .timing import median_ms, wall_ms

__all__ = ["benchmark_segmentation"]


def benchmark_segmentation(frames: int = 30, stride: int = 6) -> dict[str, float]:
    """Milliseconds per frame of person segmentation on ``frames`` demo frames.

    Frames are taken every ``stride``-th frame of the demo; the one-frame figure is the median
    over the frames after a warm-up call, so that a loaded machine's hiccups count less.
    Returns ``{"segment_person_ms": ..., "segment_person_batch_ms": ...}``: one frame per
    call, and all frames in one batched call (per frame).
    """
    stream = open_demo_stream(frame_range=FrameRange(0, max(frames, 1) * stride))
    depth = [
        torch.from_numpy(f.depth_mm.astype(np.float32) * 1e-3)
        for f in stream
        if f.index % stride == 0
    ]
    intr = stream.intrinsics
    cfg = SegmentationConfig()
    # Warm-up (imports, allocator) on the first frame, then each frame once, the first last.
    each = itertools.cycle(depth)
    one_ms = median_ms(lambda: segment_person(next(each), intr, cfg), repeats=len(depth), warmup=1)
    batch = torch.stack(depth)
    batch_ms = wall_ms(lambda: segment_person(batch, intr, cfg)) / len(depth)
    return {"segment_person_ms": float(one_ms), "segment_person_batch_ms": batch_ms}


if __name__ == "__main__":
    torch.set_num_threads(1)
    for name, ms in benchmark_segmentation().items():
        print(f"{name:<28s} {ms:8.3f} ms/frame")

"""``summary.json``: what a tracking run did, written atomically.

Keys::

    format, version         "depthmocap-result", 1
    complete                false while the run is going (the file is refreshed about once
                            a second), true once the writer was closed
    frames                  poses written (lines of poses.jsonl)
    first_frame, last_frame stream indices of the first and last written frame (null if none)
    fps                     processing rate: (frames - 1) / (wall time between the first
                            and the last written frame); null with fewer than two frames
    stream_fps              nominal rate of the input stream (BVH frame time = 1 / stream_fps)
    status_counts           {"tracked": n, "detected": n, "lost": n}
    mode, source            as given by the caller (e.g. "hybrid", "recording:/path")
    intrinsics              the depth camera (width, height, fx, fy, cx, cy)
    timing                  started / finished (ISO 8601 UTC), wall_s (writer open -> last
                            update), mean_frame_interval_ms
    files                   names of the result's files
    bvh                     units and world frame of motion.bvh
    extra                   anything the caller added (``ResultWriter.extra``)
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

__all__ = ["RESULT_FORMAT", "RESULT_VERSION", "write_summary", "json_safe"]

RESULT_FORMAT = "depthmocap-result"
RESULT_VERSION = 1


def json_safe(value):
    """``value`` with non-finite floats replaced by None (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def write_summary(path: str | Path, summary: dict) -> None:
    """Write ``summary`` as JSON via a temporary file and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(json_safe(summary), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)

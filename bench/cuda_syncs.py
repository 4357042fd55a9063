"""``python -m depthmocap.bench.cuda_syncs``: the source lines where the whole hybrid makes the
host wait for the GPU, counted per frame, so that a session with a GPU knows what to remove
first (the CUDA path is launch- and sync-bound: ``docs/results.md``). A diagnostic printed for
a person, never asserted.

torch's sync debug mode warns at every operation that synchronizes with the device (``.item()``,
``nonzero``, boolean-mask indexing, copies to the host); each warning is attributed to the
innermost frame of this project's code on the stack.
"""

from __future__ import annotations

import argparse
import collections
import itertools
import sys
import traceback
import warnings
from pathlib import Path

import torch
from depthmocap.runtime.api import Tracker
from depthmocap.runtime.streams import open_stream

__all__ = ["main", "sync_sites"]

_PACKAGE_ROOT = Path(__file__).resolve().parents[1]
# The project's code: its four packages (the checkout also holds tests and scripts).
_PROJECT_DIRS = tuple(_PACKAGE_ROOT / name for name in ("runtime", "shared", "train", "bench"))


def _own_frame(stack: list[traceback.FrameSummary]) -> str:
    """The innermost ``file:line (function)`` of this project's code in ``stack``."""
    for frame in reversed(stack):
        path = Path(frame.filename).resolve()
        own = any(path.is_relative_to(d) for d in _PROJECT_DIRS)
        if own and path != Path(__file__).resolve():
            return f"{path.relative_to(_PACKAGE_ROOT)}:{frame.lineno} ({frame.name})"
    return "outside the project"


def sync_sites(source: str, frames: int, warmup: int = 3) -> collections.Counter:
    """Track ``warmup`` then ``frames`` frames of ``source`` on CUDA; count the synchronizing
    operations by the project line that called them."""
    if not torch.cuda.is_available():
        raise RuntimeError("cuda_syncs needs a CUDA device")
    tracker = Tracker(device="cuda")
    counts: collections.Counter = collections.Counter()
    original = warnings.showwarning

    def record(message, category, filename, lineno, file=None, line=None):
        if "synchroniz" in str(message):
            counts[_own_frame(traceback.extract_stack())] += 1
        else:
            original(message, category, filename, lineno, file, line)

    with open_stream(source) as stream:
        it = iter(stream)
        for frame in itertools.islice(it, warmup):
            tracker.track(frame)
        torch.cuda.synchronize()
        torch.cuda.set_sync_debug_mode("warn")
        try:
            with warnings.catch_warnings():  # restores the filters and showwarning on exit
                warnings.simplefilter("always")
                warnings.showwarning = record
                for frame in itertools.islice(it, frames):
                    tracker.track(frame)
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="demo", help="any runtime-track --input")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--rows", type=int, default=40)
    args = parser.parse_args(argv)
    try:
        counts = sync_sites(args.source, args.frames)
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    total = sum(counts.values())
    print(f"host syncs per frame: {total / args.frames:.0f} ({len(counts)} source lines)")
    for site, n in counts.most_common(args.rows):
        print(f"{n / args.frames:8.1f}  {site}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How often the person segmentation misses the person, on recordings with true labels.

    python -m depthmocap.bench.segmentation_accuracy --recordings data/dev_broad [--every 1] \
        [--segmentation-config YAML]

Each recording is segmented twice: frame by frame as one stream (:class:`PersonSegmenter`, what
``runtime-track`` does) and every frame on its own (:func:`segment_person`, no memory). A frame
*misses* when the mask and the true person pixels (the recording's labels) overlap less than
half (intersection over union below 0.5: another object, or nothing, was taken for the
person); frames where the person is out of view are counted apart. Prints the totals and the
recordings with a miss. The segmentation before the person was chosen by shape and
continuity is the single-image figure with ``convex_weight: 1.0`` (every component counts
with its whole area, the largest wins).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.runtime.segmentation import PersonSegmenter, SegmentationConfig, segment_person
from depthmocap.shared.recording import Recording, RecordingError

__all__ = ["mask_iou", "segmentation_misses", "main"]

MISS_IOU = 0.5


def mask_iou(mask: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks (1 when both are empty)."""
    union = int((mask | truth).sum())
    return 1.0 if union == 0 else int((mask & truth).sum()) / union


def segmentation_misses(
    rec: Recording, every: int = 1, cfg: SegmentationConfig | None = None
) -> dict[str, np.ndarray]:
    """Per evaluated frame of ``rec``: IoU of the stream's mask and of the single-image mask
    with the true person, and whether the person is in view (any true pixel)."""
    stream = PersonSegmenter(cfg)
    out = {"stream": [], "single": [], "in_view": []}
    for i in range(len(rec)):
        depth = torch.from_numpy(rec.read_depth(i).astype(np.float32))
        mask = stream(depth, rec.intrinsics)  # every frame, so the stream's memory is real
        if i % every:
            continue
        truth = rec.read_labels(i) > 0
        out["stream"].append(mask_iou(mask.numpy(), truth))
        out["single"].append(mask_iou(segment_person(depth, rec.intrinsics, cfg).numpy(), truth))
        out["in_view"].append(bool(truth.any()))
    return {k: np.array(v) for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.bench.segmentation_accuracy", description=__doc__.split("\n")[0]
    )
    p.add_argument("--recordings", type=Path, required=True, help="folder of recordings")
    p.add_argument("--every", type=int, default=1, help="evaluate every k-th frame")
    p.add_argument(
        "--segmentation-config", type=Path, help="YAML of SegmentationConfig keys (default: none)"
    )
    args = p.parse_args(argv)
    if args.every < 1:
        p.error("--every must be >= 1")
    from depthmocap.shared.config import ConfigError, load_config

    try:
        cfg = load_config(SegmentationConfig, args.segmentation_config)
    except (ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    folders = sorted(d for d in args.recordings.iterdir() if (d / "meta.json").is_file())
    if not folders:
        print(f"error: no recordings in {args.recordings}", file=sys.stderr)
        return 2
    totals = {"stream": 0, "single": 0, "frames": 0, "out_of_view": 0}
    for d in folders:
        try:
            rec = Recording(d)
        except RecordingError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        if not rec.has_labels:
            print(f"error: {d} has no labels to check against", file=sys.stderr)
            return 2
        r = segmentation_misses(rec, args.every, cfg)
        seen = r["in_view"]
        miss = {k: int((r[k][seen] < MISS_IOU).sum()) for k in ("stream", "single")}
        totals["frames"] += int(seen.sum())
        totals["out_of_view"] += int((~seen).sum())
        for k in miss:
            totals[k] += miss[k]
        if miss["stream"] or miss["single"]:
            print(f"{d.name:48s} missed: stream {miss['stream']:3d}, single images "
                  f"{miss['single']:3d} of {int(seen.sum())}")  # fmt: skip
    n = max(totals["frames"], 1)
    print(f"{len(folders)} recordings, {totals['frames']} frames with the person in view "
          f"({totals['out_of_view']} without, not counted)")  # fmt: skip
    print(f"person missed (IoU < {MISS_IOU}): stream {totals['stream']} frames "
          f"({100 * totals['stream'] / n:.2f}%), single images {totals['single']} "
          f"({100 * totals['single'] / n:.2f}%)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

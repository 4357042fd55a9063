"""``python -m depthmocap.train.synth.contact_sheet``: a PNG grid of depth + label frames of a
training set or a recording, for looking at the data (are bodies human, do labels line up, is the
noise right)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared.labels import PART_COLORS


def depth_to_bgr(depth_mm: np.ndarray, far_mm: float = 5000.0) -> np.ndarray:
    """Colour-mapped depth (near = red, far = blue), black where there is no reading: (H, W, 3)."""
    import cv2

    scaled = (np.clip(depth_mm / far_mm, 0, 1) * 255).astype(np.uint8)
    out = cv2.applyColorMap(255 - scaled, cv2.COLORMAP_JET)
    out[depth_mm == 0] = 0
    return out


def labels_to_bgr(labels: np.ndarray) -> np.ndarray:
    return PART_COLORS[labels][..., ::-1].copy()


def contact_sheet(depth: np.ndarray, labels: np.ndarray, columns: int = 6) -> np.ndarray:
    """Tiles of depth above labels for N frames: depth, labels (N, H, W) -> (rows*2H, cols*W, 3)."""
    tiles = [np.concatenate([depth_to_bgr(d), labels_to_bgr(lab)], 0) for d, lab in
             zip(depth, labels)]  # fmt: skip
    while len(tiles) % columns:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.concatenate(tiles[i : i + columns], 1) for i in range(0, len(tiles), columns)]
    return np.concatenate(rows, 0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="train-contact-sheet", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="training-set directory or recording directory")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--count", type=int, default=18, help="number of frames")
    p.add_argument("--seed", type=int, default=0, help="which frames (random, reproducible)")
    args = p.parse_args(argv)
    import cv2

    root = Path(args.data)
    try:
        if (root / "manifest.json").is_file():
            from depthmocap.train.synth.trainset import TrainSet

            ts = TrainSet(root)
            rng = np.random.default_rng(args.seed)
            idx = rng.choice(ts.frames, min(args.count, ts.frames), replace=False)
            shard = ts.load_frames(idx)
            depth, labels = shard.depth, shard.labels
        else:
            from depthmocap.shared.recording import Recording

            rec = Recording(root)
            idx = np.linspace(0, len(rec) - 1, min(args.count, len(rec))).astype(int)
            depth = np.stack([rec.read_depth_mm(i) for i in idx])
            labels = np.stack(
                [rec.read_labels(i) if rec.has_labels else np.zeros_like(depth[0], np.uint8)
                 for i in idx]
            )  # fmt: skip
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cv2.imwrite(args.out, contact_sheet(depth, labels))
    print(f"wrote {args.out} ({len(depth)} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``train-import``: convert other depth datasets into the project's recordings.

    train-import --utd-mhad DIR --out DIR [--actions 5 22] [--subjects 1] [--trials 1]
                 [--max-frames N] [--skeleton-lag N] [--overwrite]

UTD-MHAD (:mod:`train.importers.utd_mhad`): one recording per take, named ``a05_s1_t1``, with
the un-mirrored depth, the camera's intrinsics and the Kinect SDK's skeleton as
``reference.npz`` (another tracker, not ground truth), each skeleton paired with the depth
frame that shows the same moment (``--skeleton-lag``: the dataset's depth stream runs 2 frames
late, so the first 2 depth frames, which have no skeleton, are not imported). A recording
already imported (its ``reference.npz`` written last) with the same pairing is skipped unless
``--overwrite``; one paired otherwise is imported again. Exit
status 2 with one ``error:`` line on a missing folder, a missing or malformed ``.mat`` file or
no matching take.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from depthmocap.shared.recording import RecordingWriter

from . import utd_mhad as utd

__all__ = ["main", "build_parser", "import_utd_sequence"]


def import_utd_sequence(
    seq: utd.Sequence,
    out: Path,
    max_frames: int | None = None,
    overwrite: bool = False,
    lag: int = utd.SKELETON_LAG_FRAMES,
) -> int:
    """Write one take as the recording ``out``; returns its frame count.

    Both files are read and checked before anything is written, so a malformed take leaves
    no half recording behind.

    Args:
        max_frames: keep at most this many frames (after pairing the streams; None: all).
        lag: :func:`utd_mhad.align_streams`'s lag in frames.
    """
    depth, skel = utd.read_sequence(seq, None if max_frames is None else max_frames + lag)
    depth, skel = utd.align_streams(depth, skel, lag)
    # An interrupted import (meta.json but no reference.npz) is replaced without asking.
    overwrite = overwrite or not (out / "reference.npz").is_file()
    intr = utd.utd_intrinsics()
    with RecordingWriter(out, intr, utd.FPS, seq.source, overwrite) as writer:
        for frame in utd.unmirror_depth(depth):
            writer.write_frame(frame)
        writer.write_reference(
            utd.kinect_to_camera(skel),
            utd.KINECT_JOINTS,
            utd.reference_source(lag),
            utd.JOINT_MAP,
        )
    return len(depth)


def _paired_as(out: Path, lag: int) -> bool:
    """Whether the recording ``out`` was imported with this skeleton lag (an import made with
    another, or before the lag existed, is re-imported rather than kept: results scored
    against it would compare other moments)."""
    import numpy as np

    try:
        with np.load(out / "reference.npz") as ref:
            return str(ref["source"]) == utd.reference_source(lag)
    except (OSError, ValueError, KeyError):
        return False  # unreadable: imported again


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-import", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--utd-mhad", required=True, type=Path, metavar="DIR",
        help="UTD-MHAD folder holding Depth/ and Skeleton/",
    )  # fmt: skip
    p.add_argument("--out", required=True, type=Path, help="folder of recordings to write")
    p.add_argument("--actions", type=int, nargs="+", help="only these action numbers")
    p.add_argument("--subjects", type=int, nargs="+", help="only these subjects")
    p.add_argument("--trials", type=int, nargs="+", help="only these trials")
    p.add_argument("--max-frames", type=int, help="only the first N frames of each take")
    p.add_argument(
        "--skeleton-lag", type=int, default=utd.SKELETON_LAG_FRAMES, metavar="N",
        help="pair each skeleton with the depth frame N later (the stored depth runs late; "
        f"default {utd.SKELETON_LAG_FRAMES}, measured by "
        "python -m depthmocap.train.evaluation.reference_lag; 0: as stored)",
    )  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="re-import recordings already there")
    p.add_argument("--quiet", "-q", action="store_true", help="no line per recording")
    return p


def _selected(seqs: list[utd.Sequence], args: argparse.Namespace) -> list[utd.Sequence]:
    def keep(value: int, wanted: list[int] | None) -> bool:
        return wanted is None or value in wanted

    return [
        s for s in seqs
        if keep(s.action, args.actions) and keep(s.subject, args.subjects)
        and keep(s.trial, args.trials)
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.max_frames is not None and args.max_frames < 1:
        print("error: --max-frames must be at least 1", file=sys.stderr)
        return 2
    if args.skeleton_lag < 0:
        print("error: --skeleton-lag must be 0 or more", file=sys.stderr)
        return 2
    try:
        seqs = _selected(utd.find_sequences(args.utd_mhad), args)
        if not seqs:
            raise utd.UtdError(f"{args.utd_mhad}: no take matches the filters")
        written = skipped = repaired = frames = 0
        for seq in seqs:
            out = args.out / seq.name
            there = (out / "reference.npz").is_file()
            stale = there and not _paired_as(out, args.skeleton_lag)
            if there and not stale and not args.overwrite:
                skipped += 1
                continue
            n = import_utd_sequence(
                seq, out, args.max_frames, args.overwrite or stale, args.skeleton_lag
            )
            written, frames, repaired = written + 1, frames + n, repaired + stale
            if not args.quiet:
                print(f"wrote {out} ({n} frames)")
    except (utd.UtdError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(
        f"{written} recordings ({frames} frames) written to {args.out}"
        + (f", {skipped} already there (--overwrite re-imports them)" if skipped else "")
        + (f"; {repaired} of them replaced an import paired otherwise" if repaired else "")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

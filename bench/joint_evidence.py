"""Record what the shipped hybrid says about each joint, for fitting its confidence.

    python -m depthmocap.bench.joint_evidence --recordings data/tune_half_a --out out/evidence

Each recording is tracked as ``runtime-track`` runs a file (the population body, the shipped
settings with ``--config`` laid over them; the observed flags from the tracker's own area
test, ``joint_confidence`` off; the look-back's refits in place of the frames they revised,
as the poses a file gets are written), and every frame with a pose gives a line of evidence: the
joints' confirmed areas, the limbs' visibility in the fit, the output joints and the flags.
One ``NAME.npz`` per recording (written whole, so an interrupted run resumes at the next
recording; one already there is kept). ``python -m
depthmocap.train.evaluation.joint_confidence_fit`` pairs them with the ground truth (``train``
never imports ``runtime``; this is the runtime side).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.runtime.api import Tracker
from depthmocap.runtime.estimator import estimate_frame, make_estimator, prepare_frame
from depthmocap.runtime.estimator_setup import load_body
from depthmocap.runtime.look_back import MAX_LOOK_BACK, LookBack, file_hold, looked_back
from depthmocap.runtime.segmentation import PersonSegmenter
from depthmocap.runtime.streams import open_stream
from depthmocap.shared import skeleton as sk
from depthmocap.shared.config import load_settings, merged_settings
from depthmocap.shared.image_cut import image_cut_distance_m
from depthmocap.shared.joint_confidence import FRAME_FEATURES, frame_features
from depthmocap.shared.part_evidence import image_part_evidence

__all__ = ["main", "record_evidence", "track_evidence"]


def track_evidence(
    recording: Path, config: str | None = None, look_back: int | None = None
) -> dict[str, np.ndarray]:
    """Track ``recording`` (module docstring); ``look_back``: frames held for the look-back
    (None: as ``runtime-track`` holds a file; 0: each estimate as the forward track left it).

    Returns:
        ``frame`` (F,) indices of the frames with a pose, ``support`` (F, J) confirmed areas
        (cm^2), ``visibility`` (F, 4) of the limbs in the fit, ``joints`` (F, J, 3) output
        joints, ``cut_m`` (F, J) their distances to the person's cut by the image's edge
        (metres, inf where the person is whole), ``fit`` (F, 5) the frame's fit
        (``shared.joint_confidence.frame_features``), ``observed`` (F, J) bool the area
        test's flags, ``parts`` (F, J, 2) each joint's distance to the forest's pixels of its
        parts and their count (``shared.part_evidence``).
    """
    # The flags recorded beside the evidence are the tracker's own area test's.
    overlay = merged_settings(load_settings(config) if config else {}, {"joint_confidence": None})
    tracker = Tracker(config=overlay)
    keys = ("frame", "support", "visibility", "joints", "cut_m", "fit", "observed", "parts")
    rows: dict[str, list] = {k: [] for k in keys}
    segment = PersonSegmenter(tracker.segmentation)  # a stream's own, as runtime-track's
    with open_stream(str(recording)) as stream:
        estimator = make_estimator(
            tracker.mode, tracker.model, load_body(None), stream.intrinsics, tracker.device,
            tracker.settings,
        )  # fmt: skip

        def estimates():
            for frame in stream:
                prepared = prepare_frame(estimator, frame, segment, tracker.device)
                yield prepared, estimate_frame(estimator, prepared)

        held = file_hold(estimator) if look_back is None else look_back
        stage = LookBack.for_estimator(estimator, held)
        pairs = estimates() if stage is None else looked_back(estimates(), stage)
        try:
            for prepared, est in pairs:
                cut = parts = None
                if est.joints is not None:  # the mask as the estimate left it
                    joints = torch.as_tensor(est.joints, dtype=torch.float64)
                    cut = image_cut_distance_m(prepared.mask.cpu(), joints, stream.intrinsics)
                    labels = prepared.labels(estimator.label_source)
                    parts = (
                        image_part_evidence(
                            prepared.depth_m, prepared.mask, labels, stream.intrinsics, joints
                        )
                        .cpu()
                        .numpy()
                    )
                fit = frame_features(est.errors, est.status)
                values = (prepared.index, est.joint_support_cm2, est.limb_visibility, est.joints,
                          cut, fit, est.observed, parts)  # fmt: skip
                if all(v is not None for v in values):  # a frame with a pose and its evidence
                    for key, value in zip(keys, values, strict=True):
                        rows[key].append(value)
        finally:
            close = getattr(estimator, "close", None)
            if close is not None:
                close()
    J = len(sk.JOINT_NAMES)
    return {
        "frame": np.asarray(rows["frame"], dtype=np.int64),
        "support": np.asarray(rows["support"], dtype=np.float64).reshape(-1, J),
        "visibility": np.asarray(rows["visibility"], dtype=np.float64).reshape(-1, 4),
        "joints": np.asarray(rows["joints"], dtype=np.float64).reshape(-1, J, 3),
        "cut_m": np.asarray(rows["cut_m"], dtype=np.float64).reshape(-1, J),
        "fit": np.asarray(rows["fit"], dtype=np.float64).reshape(-1, len(FRAME_FEATURES)),
        "observed": np.asarray(rows["observed"], dtype=bool).reshape(-1, J),
        "parts": np.asarray(rows["parts"], dtype=np.float64).reshape(-1, J, 2),
    }


def record_evidence(
    recordings: list[Path], out: Path, config: str | None = None, look_back: int | None = None
) -> list[Path]:
    """:func:`track_evidence` of each recording into ``out/NAME.npz`` (kept where present);
    the files, in the recordings' order."""
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for rec in recordings:
        path = out / f"{rec.name}.npz"
        if not path.is_file():
            tmp = out / f"{rec.name}.tmp.npz"
            np.savez(tmp, **track_evidence(rec, config, look_back))
            tmp.replace(path)
            print(f"  {rec.name}", flush=True)
        files.append(path)
    return files


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.bench.joint_evidence", description=__doc__.splitlines()[0]
    )
    p.add_argument("--recordings", type=Path, nargs="+", required=True,
                   help="recordings, or folders of them")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="folder for one NAME.npz each")
    p.add_argument("--config", default=None, help="settings over the shipped preset")
    p.add_argument("--look-back", type=int, default=None,
                   help="frames held for the look-back (default: as runtime-track holds a "
                        "file, so the evidence is of the poses it writes; 0: the forward "
                        "track's)")  # fmt: skip
    args = p.parse_args(argv)
    if args.look_back is not None and not 0 <= args.look_back <= MAX_LOOK_BACK:
        p.error(f"--look-back must be 0-{MAX_LOOK_BACK} frames, got {args.look_back}")
    recordings = []
    for path in args.recordings:
        if (path / "meta.json").is_file():
            recordings.append(path)
        elif path.is_dir():
            recordings += sorted(r for r in path.iterdir() if (r / "meta.json").is_file())
        else:
            p.error(f"{path}: no such recording or folder")
    record_evidence(recordings, args.out, args.config, args.look_back)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``runtime-personalize``: the user's body shape from two depth views (Helten et al. 2013, III).

    runtime-personalize --input DIR --output body.json
    runtime-personalize --front REC --back REC --output body.json [--mesh-out fit.npz]

``DIR`` holds two recordings, ``DIR/front`` (the person facing the camera) and ``DIR/back``
(turned around), in the reference calibration pose (arms lowered about 40 degrees sideways,
feet slightly apart; held roughly is enough). One frame of each is used (``--front-frame``,
``--back-frame``; default: the middle frame). The person is segmented from floor and
background (:mod:`runtime.segmentation`), one anny shape and one pose per view are fitted
jointly (:mod:`runtime.personalize.fit`), and the tracker's body (segment lengths, radii,
extents; :mod:`runtime.personalize.body_from_mesh`) is written as a body file for
``runtime-track --body``. ``--mesh-out`` also saves the fitted rest mesh, phenotype, local
coefficients, poses and timings (``.npz``). Needs the optional body model:
``pip install 'depthmocap[personalize]'``. Bad inputs end with a one-line ``error:`` and exit
status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.config import ConfigError, add_cli_args, config_from_args
from depthmocap.shared.recording import Recording, RecordingError

from .cli_common import check_output_file, report_error
from .personalize.fit import FitConfig, PersonalizeError

__all__ = ["main", "load_view"]

MIN_PERSON_POINTS = 500


def load_view(path: Path, frame: int | None, name: str) -> tuple[torch.Tensor, Intrinsics, tuple]:
    """The segmented person's points (N, 3) of one frame of a recording, its camera, and the
    floor (normal, point, band) that segmentation cut away (None without a floor)."""
    from .segmentation import SegmentationConfig, depth_valid_mask, fit_floor_plane, segment_person

    rec = Recording(path)
    if len(rec) == 0:
        raise PersonalizeError(f"{name} view {path}: the recording has no frames")
    index = len(rec) // 2 if frame is None else frame
    if not 0 <= index < len(rec):
        raise PersonalizeError(
            f"{name} view {path}: frame {index} out of range (0..{len(rec) - 1})"
        )
    depth = torch.as_tensor(rec.read_depth(index), dtype=torch.float64)
    seg_cfg = SegmentationConfig()
    mask = segment_person(depth, rec.intrinsics, seg_cfg)
    cloud = depth_to_points(depth[None], rec.intrinsics)
    points = cloud[0][mask]
    if len(points) < MIN_PERSON_POINTS:
        raise PersonalizeError(
            f"{name} view {path}: no person found in frame {index} "
            f"({len(points)} person pixels, need {MIN_PERSON_POINTS})"
        )
    floor = None
    if seg_cfg.remove_floor:
        normal, centre, found = fit_floor_plane(
            cloud, depth_valid_mask(depth[None], seg_cfg), seg_cfg
        )
        if bool(found[0]):
            floor = (normal[0], centre[0], seg_cfg.floor_band_m)
    return points, rec.intrinsics, floor


def _view_paths(args: argparse.Namespace) -> tuple[Path, Path]:
    if args.input is not None:
        if args.front or args.back:
            raise PersonalizeError("give either --input DIR or --front/--back, not both")
        root = Path(args.input)
        if not root.is_dir():
            raise PersonalizeError(f"{root}: no such directory")
        missing = [v for v in ("front", "back") if not (root / v).is_dir()]
        if missing:
            raise PersonalizeError(
                f"{root}: needs two recordings front/ and back/; missing {', '.join(missing)} "
                "(personalization needs both views)"
            )
        return root / "front", root / "back"
    if not args.front or not args.back:
        raise PersonalizeError(
            "personalization needs two views: give --input DIR or both --front and --back"
        )
    return Path(args.front), Path(args.back)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runtime-personalize",
        description="Fit the user's body shape to a front and a back depth view; write a "
        "body file for runtime-track --body.",
    )
    p.add_argument("--input", help="directory with the recordings front/ and back/")
    p.add_argument("--front", help="recording of the front view (instead of --input)")
    p.add_argument("--back", help="recording of the back view (instead of --input)")
    p.add_argument("--front-frame", type=int, help="frame of the front view (default: middle)")
    p.add_argument("--back-frame", type=int, help="frame of the back view (default: middle)")
    p.add_argument("--output", required=True, help="body file (JSON) to write")
    p.add_argument("--mesh-out", help="also save the fitted mesh and parameters (.npz)")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (the fit is many small operations: 1 was 4x faster than 2 on "
        "the shared 2-core machine)",
    )
    add_cli_args(p, FitConfig)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    torch.set_num_threads(max(args.threads, 1))
    try:
        cfg = config_from_args(FitConfig, args)
        out = check_output_file(args.output)  # before the fit: it takes a while
        if args.mesh_out:
            check_output_file(args.mesh_out)
        front, back = _view_paths(args)
        start = time.perf_counter()
        (pf, intr_f, floor_f), (pb, intr_b, floor_b) = (
            load_view(front, args.front_frame, "front"),
            load_view(back, args.back_frame, "back"),
        )
        if intr_f != intr_b:
            raise PersonalizeError(
                f"front and back views come from different cameras ({intr_f} vs {intr_b})"
            )
        from .personalize.body_from_mesh import body_from_rest
        from .personalize.fit import fit_shape
        from .personalize.shape_model import load_shape_model

        t_load = time.perf_counter()
        model = load_shape_model()
        t_fit = time.perf_counter()
        result = fit_shape(
            model, [pf, pb], intr_f, ("front", "back"), cfg, floors=[floor_f, floor_b]
        )
        body = body_from_rest(model, result.rest)
    except (PersonalizeError, RecordingError, ConfigError, ValueError) as err:
        return report_error(err)
    try:
        body.save(out)
    except OSError as err:
        return report_error(f"{out}: cannot write ({err.strerror or err})")
    timings = {
        "read_segment_s": t_load - start,
        "model_load_s": t_fit - t_load,
        "fit_s": result.seconds,
        "total_s": time.perf_counter() - start,
    }
    if args.mesh_out:
        try:
            np.savez_compressed(
                args.mesh_out,
                rest_vertices=result.rest.vertices[0].numpy().astype(np.float32),
                faces=model.faces.numpy().astype(np.int32),
                vertex_segment=model.vertex_segment.numpy().astype(np.int8),
                phenotype=result.phenotype,
                local=result.local,
                q=result.q,
                rms_m=result.rms_m,
                timings=np.array(json.dumps(timings)),
            )
        except OSError as err:
            return report_error(f"{args.mesh_out}: cannot write ({err.strerror or err})")
    print(
        f"wrote {out}: stature {float(body.stature()):.3f} m, fit {result.seconds:.1f} s "
        f"({result.iterations} iterations), residual RMS "
        + " / ".join(f"{1000 * r:.1f}" for r in result.rms_m)
        + " mm (front / back)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

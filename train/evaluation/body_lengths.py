"""How far estimated bodies' bone lengths are from the bodies the recordings were rendered with.

Issue 6's calibration target (Wei section 6): calibrated bone lengths within 2 cm of the
rendered body's. The reference is each dev recording's ``body.json`` (the cylinder model
fitted to the rendered mesh); it is read here for evaluation only, never at run time. The
rest of the body's shape is compared too (radii, the sections' offsets from the joint axis,
the hip half-width, the feet): a body with the right lengths and a pelvis 6 cm too thin
still tracks badly.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape

__all__ = ["bone_length_errors", "format_bone_length_errors"]


def bone_length_errors(estimated: Sequence[Path], reference: Sequence[Path]) -> dict:
    """Absolute bone-length differences of body files, paired in order.

    Returns:
        ``bodies``: how many pairs; ``mean_cm``: the mean over bodies and segments;
        ``per_segment_cm``: {segment: mean over bodies}; ``per_body_cm``: the mean over
        segments of each pair; ``max_cm``: the largest single difference;
        ``shape_mean_cm``: {radii, offsets, hip_half_width, feet: the mean absolute
        difference over bodies and entries}.

    Raises:
        ValueError: unequal numbers of paths, or none. A missing or corrupt body file raises
            the body loader's error, naming the file.
    """
    if len(estimated) != len(reference) or not estimated:
        raise ValueError(
            f"need matching, non-empty lists of body files, got {len(estimated)} estimated "
            f"and {len(reference)} reference"
        )
    pairs = [(BodyShape.load(e), BodyShape.load(r)) for e, r in zip(estimated, reference)]

    def diff_cm(field: str) -> np.ndarray:  # (N, ...) |estimated - reference|, cm
        return 100.0 * np.stack(
            [np.abs(getattr(e, field).numpy() - getattr(r, field).numpy()) for e, r in pairs]
        ).astype(np.float64)

    err = diff_cm("lengths")  # (N, 15)
    return {
        "bodies": len(err),
        "mean_cm": float(err.mean()),
        "per_segment_cm": dict(zip(sk.SEGMENT_NAMES, err.mean(0).round(3).tolist())),
        "per_body_cm": err.mean(1).round(3).tolist(),
        "max_cm": float(err.max()),
        "shape_mean_cm": {
            k: float(diff_cm(k).mean()) for k in ("radii", "offsets", "hip_half_width", "feet")
        },
    }


def format_bone_length_errors(kind: str, errors: dict) -> str:
    """One paragraph: the mean, the worst segments, the largest single bone, the shape."""
    worst = sorted(errors["per_segment_cm"].items(), key=lambda kv: -kv[1])[:3]
    return (
        f"{kind} bodies ({errors['bodies']}): bone lengths {errors['mean_cm']:.2f} cm off on "
        f"average against the rendered bodies (worst segments: "
        + ", ".join(f"{k} {v:.2f}" for k, v in worst)
        + f"; largest single bone {errors['max_cm']:.1f} cm; worst body "
        f"{max(errors['per_body_cm']):.2f} cm); shape: "
        + ", ".join(f"{k.replace('_', ' ')} {v:.2f}" for k, v in errors["shape_mean_cm"].items())
        + " cm off on average"
    )

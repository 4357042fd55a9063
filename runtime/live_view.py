"""Optional live 3D view of tracking in rerun (``runtime-track --view``).

Per frame it logs the person's depth points (coloured by the estimator's part labels when it
has them), the skeleton as line strips and the status. ``rerun-sdk`` is optional
(``pip install 'depthmocap[view]'``) and imported only when a view is asked for. With a file
path the recording is saved (``.rrd``, open it with ``rerun FILE``) instead of spawning the
viewer, which also works on a machine without a display.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import depth_to_points
from depthmocap.shared.labels import PART_COLORS

__all__ = ["LiveViewError", "LiveView", "BONES"]

BONES = np.array([[sk.JOINT_NAMES.index(a), sk.JOINT_NAMES.index(b)] for a, b in sk.JOINT_BONES])
_STATUS_COLOURS = {"tracked": (60, 220, 60), "detected": (250, 200, 40), "lost": (230, 60, 60)}
_INFERRED_COLOUR = (128, 128, 128)


class LiveViewError(ValueError):
    """The live view cannot start (rerun-sdk missing)."""


class LiveView:
    """Streams frames to rerun.

    Args:
        save_path: write a ``.rrd`` recording here instead of spawning the viewer.
    """

    def __init__(self, save_path: str | Path | None = None) -> None:
        try:
            import rerun as rr
        except ImportError:
            raise LiveViewError(
                "the live view needs rerun-sdk: pip install 'depthmocap[view]'"
            ) from None
        self.rr = rr
        rr.init("depthmocap", spawn=save_path is None)
        if save_path is not None:
            rr.save(str(save_path))
        # Camera frame is OpenCV's (y down); tell the viewer so "up" looks right.
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)

    def log_frame(self, frame, estimate) -> None:
        """One frame (a ``runtime.frame.Frame``): the person's depth points, skeleton, status."""
        rr = self.rr
        rr.set_time("frame", sequence=int(frame.index))
        depth = frame.depth_m.detach().cpu()
        m = frame.mask.detach().cpu() & (depth > 0)
        points = depth_to_points(depth, frame.intrinsics)[m].numpy()
        colours = None
        if estimate.labels is not None:
            colours = PART_COLORS[np.asarray(estimate.labels)[m.numpy()]]
        rr.log("world/person", rr.Points3D(points, colors=colours, radii=0.004))
        colour = _STATUS_COLOURS.get(estimate.status, (200, 200, 200))
        if estimate.joints is not None:
            joints = np.asarray(estimate.joints)
            rr.log(
                "world/skeleton",
                rr.LineStrips3D(joints[BONES], colors=colour, radii=0.01),
            )
            # Inferred joints (not confirmed by the depth image) in grey.
            seen = estimate.observed_or_all()[:, None]
            joint_colours = np.where(seen, np.array(colour), np.array(_INFERRED_COLOUR))
            rr.log("world/joints", rr.Points3D(joints, colors=joint_colours, radii=0.02))
        else:
            rr.log("world/skeleton", rr.Clear(recursive=True))
        rr.log("status", rr.TextLog(estimate.status))

    def close(self) -> None:
        self.rr.disconnect()

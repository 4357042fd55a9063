"""The tracked joints as plain OSC messages (``runtime-track --osc HOST:PORT``).

One OSC bundle per frame (sent immediately), in this order::

    /depthmocap/frame          (i)index (f)time (s)status
    /depthmocap/joint/<name>   (f)x (f)y (f)z (i)observed        per named joint

``index`` and ``time`` are the stream's frame index and timestamp (seconds; like every value
here rounded as in ``poses.jsonl``, to 1 microsecond / micrometre), ``status`` is
``tracked``, ``detected`` or ``lost``. Joints are :data:`shared.skeleton.JOINT_NAMES` (``head``,
``neck``, ``spine``, ``pelvis``, ``l_shoulder``, ... ``r_ankle``) in camera metres (x right,
y down, z away from the camera), sent as float32: the ``poses.jsonl`` values, or with
``--smooth`` their One-Euro filtered values. ``observed`` is 1 when the depth image confirms
the joint, 0 when it is inferred, -1 when the estimator does not say. A lost frame sends only
``/depthmocap/frame``; a joint without a finite position is left out.
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.skeleton import JOINT_NAMES

__all__ = ["OSC_PREFIX", "osc_bundle"]

OSC_PREFIX = "/depthmocap"


def osc_bundle(
    index: int,
    time: float,
    status: str,
    joints: np.ndarray | None,
    observed: np.ndarray | None = None,
):
    """The OSC bundle of one frame (a ``pythonosc`` ``OscBundle``)."""
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    bundle = OscBundleBuilder(IMMEDIATELY)
    m = OscMessageBuilder(f"{OSC_PREFIX}/frame")
    m.add_arg(int(index), "i")
    m.add_arg(round(float(time), 6), "f")
    m.add_arg(str(status), "s")
    bundle.add_content(m.build())
    if joints is not None:
        j = np.asarray(joints, dtype=np.float64)
        for i, name in enumerate(JOINT_NAMES):
            if not np.isfinite(j[i]).all():
                continue
            m = OscMessageBuilder(f"{OSC_PREFIX}/joint/{name}")
            for v in j[i]:
                m.add_arg(round(float(v), 6), "f")
            m.add_arg(-1 if observed is None else int(bool(observed[i])), "i")
            bundle.add_content(m.build())
    return bundle.build()

"""Motion capture file readers (BVH, ASF/AMC) producing global joint poses in metres."""

from .amc import read_amc
from .asf import AsfBone, AsfSkeleton, read_asf
from .bvh import UNIT_SCALES, read_bvh
from .clip import MotionClip, axis_rotation, euler_to_matrix, forward_kinematics

__all__ = [
    "UNIT_SCALES",
    "AsfBone",
    "AsfSkeleton",
    "MotionClip",
    "axis_rotation",
    "euler_to_matrix",
    "forward_kinematics",
    "read_amc",
    "read_asf",
    "read_bvh",
]

"""Automatic skeleton calibration (Wei section 6): RANSAC cylinders on a reference pose."""

from .calibrate import (
    SYMMETRIC_PAIRS,
    CalibrationConfig,
    CalibrationError,
    calibrate_body,
    measure_bones,
    reference_pose,
)
from .cylinder_ransac import CylinderFit, fit_cylinder
from .pose_check import ReferencePoseWatcher, is_reference_pose, person_stature

__all__ = [
    "CalibrationConfig",
    "CalibrationError",
    "CylinderFit",
    "ReferencePoseWatcher",
    "SYMMETRIC_PAIRS",
    "calibrate_body",
    "fit_cylinder",
    "is_reference_pose",
    "person_stature",
    "measure_bones",
    "reference_pose",
]

"""Automatic skeleton calibration (Wei section 6): RANSAC cylinders on a reference pose."""

from .calibrate import (
    SYMMETRIC_PAIRS,
    CalibrationConfig,
    CalibrationError,
    ReferencePoseWatcher,
    calibrate_body,
    is_reference_pose,
    measure_bones,
    reference_pose,
)
from .cylinder_ransac import CylinderFit, fit_cylinder

__all__ = [
    "CalibrationConfig",
    "CalibrationError",
    "CylinderFit",
    "ReferencePoseWatcher",
    "SYMMETRIC_PAIRS",
    "calibrate_body",
    "fit_cylinder",
    "is_reference_pose",
    "measure_bones",
    "reference_pose",
]

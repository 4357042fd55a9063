"""Personalized body shape from two depth images (Helten et al. 2013, section III).

:mod:`.shape_model` (anny phenotype + local PCA basis, rigged with the 34-DoF skeleton),
:mod:`.fit` (joint shape and per-view pose fit) with :mod:`.reference_pose` (where it starts),
:mod:`.correspondences` (visible vertices, closest pairs, residuals) and :mod:`.jacobian` (the
posed model's derivatives), :mod:`.body_from_mesh` (the tracker's cylinder body measured on the
fitted mesh). ``anny`` is imported only when a model is loaded.
"""

from .body_from_mesh import body_from_rest, named_joints_from_bones
from .fit import FitConfig, FitResult, PersonalizeError, fit_shape
from .reference_pose import calibration_pose
from .shape_model import AnnyUnavailableError, ShapeModel, load_shape_model

__all__ = [
    "AnnyUnavailableError",
    "FitConfig",
    "FitResult",
    "PersonalizeError",
    "ShapeModel",
    "body_from_rest",
    "calibration_pose",
    "fit_shape",
    "load_shape_model",
    "named_joints_from_bones",
]

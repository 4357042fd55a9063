"""depthmocap: real-time full-body motion capture from one depth camera.

The Python API (README, "Python API")::

    from depthmocap import Tracker, open_stream, read_poses

The subpackages are the checkout's top-level folders: ``depthmocap.runtime`` (the deployable
tracker), ``depthmocap.shared`` (formats, body model, camera), ``depthmocap.train`` (synthesis,
forest training, evaluation) and ``depthmocap.bench`` (benchmarks).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from depthmocap.shared.kernel_cache import use_kernel_cache_of_these_sources

__version__ = "0.1.0"

# Before anything can import numba: its compiled kernels' cache, one folder per version of
# their sources (a stale compiled copy of a changed kernel crashed a checkout).
use_kernel_cache_of_these_sources()

# Name -> module: imported on first use, so ``import depthmocap`` stays instant and a
# script that only reads results never loads torch.
_EXPORTS = {
    "Tracker": "depthmocap.runtime.api",
    "TrackError": "depthmocap.runtime.estimator_setup",
    "PoseEstimate": "depthmocap.runtime.estimator",
    "open_stream": "depthmocap.runtime.streams",
    "DepthFrame": "depthmocap.runtime.streams",
    "Intrinsics": "depthmocap.shared.camera",
    "BodyShape": "depthmocap.shared.body",
    "read_poses": "depthmocap.shared.result_arrays",
    "Poses": "depthmocap.shared.result_arrays",
    "JOINT_NAMES": "depthmocap.shared.skeleton",
}
__all__ = [
    "Tracker",
    "TrackError",
    "PoseEstimate",
    "open_stream",
    "DepthFrame",
    "Intrinsics",
    "BodyShape",
    "read_poses",
    "Poses",
    "JOINT_NAMES",
    "__version__",
]

if TYPE_CHECKING:
    from depthmocap.runtime.api import Tracker
    from depthmocap.runtime.estimator import PoseEstimate
    from depthmocap.runtime.estimator_setup import TrackError
    from depthmocap.runtime.streams import DepthFrame, open_stream
    from depthmocap.shared.body import BodyShape
    from depthmocap.shared.camera import Intrinsics
    from depthmocap.shared.result_arrays import Poses, read_poses
    from depthmocap.shared.skeleton import JOINT_NAMES


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'depthmocap' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)

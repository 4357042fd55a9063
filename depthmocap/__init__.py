"""depthmocap: real-time full-body motion capture from one depth camera.

The Python API (README, "Python API")::

    from depthmocap import Tracker, open_stream, read_poses

The subpackages are the checkout's top-level folders: ``depthmocap.runtime`` (the deployable
tracker), ``depthmocap.shared`` (formats, body model, camera), ``depthmocap.train`` (synthesis,
forest training, evaluation) and ``depthmocap.bench`` (benchmarks).
"""

from __future__ import annotations

import hashlib
import importlib
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# Compiled-kernel caches unused for this long are deleted when another one is made.
_KERNEL_CACHE_KEEP_S = 30 * 86400


def kernel_cache_folder(code_folders: list[Path], root: Path) -> Path:
    """The numba cache folder under ``root`` for the compiled kernels (``*_kernel.py``) found
    in ``code_folders``: named by the hash of their names and sources, so any change to any
    kernel gives another folder."""
    digest = hashlib.sha1()
    for folder in code_folders:
        for path in sorted(Path(folder).rglob("*_kernel.py")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return root / f"numba-{digest.hexdigest()[:16]}"


def use_kernel_cache(folder: Path, keep_s: float = _KERNEL_CACHE_KEEP_S) -> bool:
    """Make ``folder`` numba's cache (``NUMBA_CACHE_DIR``) and delete its siblings unused for
    ``keep_s`` seconds; False (nothing changed) where it cannot be written."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)  # in use: kept by the clean-up of the others
        for other in folder.parent.glob("numba-*"):
            if other != folder and time.time() - other.stat().st_mtime > keep_s:
                import shutil

                shutil.rmtree(other, ignore_errors=True)
    except OSError:
        return False
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    return True


def _use_kernel_cache_of_these_sources() -> None:
    """Point numba's on-disk cache at :func:`kernel_cache_folder` of this install, unless the
    user set ``NUMBA_CACHE_DIR``.

    numba keys a cached function on its own file alone, and a kernel that calls another
    carries its own compiled copy of the callee: after an update that changed one kernel's
    data (a field added to a tuple it returns) but not the file of a kernel calling it, the
    caller's stale copy read the new data wrongly and crashed the process (thirty-fifth
    session, in a checkout). A folder per set of sources makes any change a fresh cache.
    Where the cache root cannot be written, numba's default (``__pycache__``) stays."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    import importlib.util

    try:  # no home folder (a bare container) or an unreadable install: numba's default
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "depthmocap"
        folders = []
        for name in ("shared", "runtime"):  # where the kernels are (bench and train have none)
            spec = importlib.util.find_spec(f"{__name__}.{name}")
            folders += list((spec and spec.submodule_search_locations) or ())
        folder = kernel_cache_folder(folders, root)
    except (OSError, RuntimeError, KeyError, ImportError):
        return
    use_kernel_cache(folder)


_use_kernel_cache_of_these_sources()

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

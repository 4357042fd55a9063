"""Where numba caches the compiled kernels: one folder per version of their sources.

numba keys a cached function on its own file alone, and a kernel that calls another carries its
own compiled copy of the callee: after an update that changed one kernel's data (a field added
to a tuple it returns) but not the file of a kernel calling it, the caller's stale copy read the
new data wrongly and crashed the process (thirty-fifth session, in a checkout). Caching under a
folder named by the hash of every kernel's source makes any change a fresh cache.

``depthmocap/__init__.py`` calls :func:`use_kernel_cache_of_these_sources` before anything can
import numba (it reads ``NUMBA_CACHE_DIR`` once, at import). Only ``os``, ``hashlib`` and
``pathlib`` are imported here, so ``import depthmocap`` stays light.
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

from .resources import PACKAGE_ROOT, cache_root

__all__ = ["kernel_cache_folder", "use_kernel_cache", "use_kernel_cache_of_these_sources"]

# Where the kernels are (``bench`` and ``train`` have none), in a checkout and installed alike.
KERNEL_FOLDERS = (PACKAGE_ROOT / "shared", PACKAGE_ROOT / "runtime")
# Kernel caches unused for this long are deleted when another one is used.
KEEP_S = 30 * 86400


def kernel_cache_folder(code_folders: tuple[Path, ...] | list[Path], root: Path) -> Path:
    """The numba cache folder under ``root`` for the compiled kernels (``*_kernel.py``) found
    in ``code_folders``: named by the hash of their names and sources, so any change to any
    kernel gives another folder."""
    digest = hashlib.sha1()
    for folder in code_folders:
        for path in sorted(Path(folder).rglob("*_kernel.py")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return root / f"numba-{digest.hexdigest()[:16]}"


def use_kernel_cache(folder: Path, keep_s: float = KEEP_S) -> bool:
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


def use_kernel_cache_of_these_sources() -> None:
    """Point numba's cache at :func:`kernel_cache_folder` of this install's kernels under the
    project's cache root (``shared.resources.cache_root``), unless the user set
    ``NUMBA_CACHE_DIR``. Where no cache root can be found or written (a bare container
    without a home folder, a read-only install), numba's default (``__pycache__``) stays."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    try:
        folder = kernel_cache_folder(KERNEL_FOLDERS, cache_root())
    except (OSError, RuntimeError, KeyError):  # Path.home() without a home; unreadable files
        return
    use_kernel_cache(folder)

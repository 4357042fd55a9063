"""The compiled loops' modules, loaded on first use.

Each ``*_kernel`` module imports numba, an optional dependency (the ``runtime`` extra), and
holds the CPU path of some torch code that stays for autograd, GPUs and installs without
numba. Callers ask :func:`compiled_module` and fall back to torch on None.
"""

from __future__ import annotations

import functools
import importlib
from types import ModuleType

__all__ = ["compiled_module"]


@functools.cache
def compiled_module(name: str) -> ModuleType | None:
    """The module ``name`` (e.g. ``depthmocap.runtime.raycast_kernel``), or None where it
    cannot be imported (numba missing)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        return None

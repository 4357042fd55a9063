"""The compiled loops' modules, loaded on first use.

Each ``*_kernel`` module imports numba, an optional dependency (the ``runtime`` extra), and
holds the CPU path of some torch code that stays for autograd, GPUs and installs without
numba. Callers ask :func:`compiled_module` (or :func:`compiled_float32` for loops that
reproduce torch's float32 arithmetic on the CPU) and fall back to torch on None.
"""

from __future__ import annotations

import functools
import importlib
from types import ModuleType

import torch

__all__ = ["compiled_module", "compiled_float32"]


@functools.cache
def compiled_module(name: str) -> ModuleType | None:
    """The module ``name`` (e.g. ``depthmocap.runtime.raycast_kernel``), or None where it
    cannot be imported (numba missing)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


def compiled_float32(name: str, *tensors: torch.Tensor) -> ModuleType | None:
    """:func:`compiled_module` ``name`` for a computation on ``tensors`` that it reproduces
    to the bit only in float32 on the CPU without autograd (the tracker's data terms): None
    where any tensor is elsewhere, of another dtype or needs gradients, or numba is missing."""
    usable = all(
        t.device.type == "cpu" and t.dtype == torch.float32 and not t.requires_grad for t in tensors
    )
    return compiled_module(name) if usable else None

"""The compiled loops' loader (shared.compiled): a module when it imports, None when numba is
missing, and each answer remembered."""

from __future__ import annotations

import sys

import pytest
import torch
from depthmocap.shared.compiled import compiled_float32, compiled_module


def test_loads_a_kernel_module_and_remembers_it():
    pytest.importorskip("numba")
    compiled_module.cache_clear()
    first = compiled_module("depthmocap.runtime.tracker.normal_kernel")
    assert first is not None and hasattr(first, "normal_equations_cpu")
    assert compiled_module("depthmocap.runtime.tracker.normal_kernel") is first


def test_none_without_numba(monkeypatch, request):
    compiled_module.cache_clear()
    request.addfinalizer(compiled_module.cache_clear)
    monkeypatch.setitem(sys.modules, "numba", None)  # "import numba" raises ImportError
    monkeypatch.delitem(sys.modules, "depthmocap.shared.smoothing_kernel", raising=False)
    assert compiled_module("depthmocap.shared.smoothing_kernel") is None


def test_compiled_float32_only_for_cpu_float32_without_gradients():
    pytest.importorskip("numba")
    name = "depthmocap.runtime.tracker.normal_kernel"
    x = torch.zeros(3)
    assert compiled_float32(name, x, x) is compiled_module(name)
    assert compiled_float32(name, x, x.double()) is None
    assert compiled_float32(name, x.requires_grad_()) is None

"""The CUDA sync-site counter: attribution to the project's lines; the clear error without a
GPU; a real count where one is present."""

from __future__ import annotations

import traceback

import pytest
import torch
from depthmocap.bench import cuda_syncs


def test_a_sync_is_attributed_to_the_innermost_project_line():
    here = traceback.extract_stack()  # this test file is outside the package
    inner = cuda_syncs._PACKAGE_ROOT / "runtime" / "api.py"
    stack = here + [traceback.FrameSummary(str(inner), 12, "track"),
                    traceback.FrameSummary("/usr/lib/torch/x.py", 5, "item")]  # fmt: skip
    assert cuda_syncs._own_frame(stack) == "runtime/api.py:12 (track)"
    assert cuda_syncs._own_frame(here) == "outside the project"


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without a GPU")
def test_without_cuda_it_says_so(capsys):
    assert cuda_syncs.main(["--frames", "1"]) == 2
    assert "needs a CUDA device" in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_counts_the_hybrids_syncs(capsys):
    assert cuda_syncs.main(["--frames", "1", "--rows", "5"]) == 0
    out = capsys.readouterr().out
    assert "host syncs per frame:" in out and ".py:" in out

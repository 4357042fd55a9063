"""Root fixtures: device and dtype parametrization, thread count, paths to ../shared data."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

# Deliberate thread count: under contention torch threads can stall (DESIGN.md).
torch.set_num_threads(2)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

_DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=_DEVICES)
def device(request) -> torch.device:
    """Every available device: CPU always, CUDA when present."""
    return torch.device(request.param)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request) -> torch.dtype:
    return request.param


@pytest.fixture
def one_thread():
    """Torch on one thread for the test: the tracker's many small ops stall on a loaded
    2-core machine when a second thread competes."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def write_trainset():
    """``write(root, depth, labels, intr, class_names=None, shard_frames=12) -> root``: a
    training set of the given (F, H, W) depth (mm) and labels in shards of ``shard_frames``
    (joints, poses and bodies zero), readable by ``TrainSet``; class names the part set's
    unless given."""
    import numpy as np
    from depthmocap.shared.labels import PART_NAMES
    from depthmocap.train.synth.trainset import Shard, write_manifest, write_shard

    def write(root, depth, labels, intr, class_names=None, shard_frames=12):
        names = tuple(class_names or PART_NAMES)
        shards = []
        for k, start in enumerate(range(0, len(depth), shard_frames)):
            s = slice(start, start + shard_frames)
            n = len(depth[s])
            sh = Shard(depth[s], labels[s], np.zeros((n, 16, 3), np.float32),
                       np.zeros((n, 34), np.float32), np.zeros(n, np.int32),
                       np.array([intr.fx, intr.fy, intr.cx, intr.cy]))  # fmt: skip
            sha = write_shard(Path(root) / f"s{k}.npz", sh)
            shards.append({"file": f"s{k}.npz", "frames": n, "sha256": sha})
        counts = np.bincount(np.asarray(labels).ravel(), minlength=len(names))
        write_manifest(Path(root), intr, shards, counts, 0, {}, class_names=names)
        return Path(root)

    return write


@pytest.fixture
def shared_data() -> Path:
    """../shared/data beside the checkout; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


def pytest_collection_modifyitems(config, items):
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)

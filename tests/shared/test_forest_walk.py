"""The forest walk: the compiled kernel (numba, shared/forest_kernel.py) reaches the same leaves
and gives the same posteriors, bit for bit, as the torch walk (shared/forest_walk.py) on random
forests and frames: probes off the image, batches, no pixels, stumps, camera scaling."""

import numpy as np
import pytest
import torch
from depthmocap.shared.forest_format import Forest, traversal_table
from depthmocap.shared.forest_walk import walk_leaf_rows, walk_posteriors

CAMERA = {"width": 40, "height": 30, "fx": 31.0, "fy": 31.0, "cx": 19.5, "cy": 14.5}


def random_forest(trees: int, depth: int, classes: int = 20, seed: int = 0, reach: float = 60.0):
    """Trees of at most ``depth`` levels, some branches ending early; offsets uniform in
    +-``reach`` pixel*metres (at 2 m, +-``reach`` / 2 pixels), thresholds in +-0.5 m."""
    rng = np.random.default_rng(seed)
    u, v, thr, left, right, leaf, roots = [], [], [], [], [], [], []

    def node(level: int) -> int:
        i = len(left)
        for a in (u, v, thr, left, right, leaf):
            a.append(None)
        if level == depth or (level > 1 and rng.random() < 0.15):
            u[i], v[i], thr[i], left[i], right[i] = (0.0, 0.0), (0.0, 0.0), 0.0, -1, -1
            leaf[i] = sum(x >= 0 for x in leaf if x is not None)
            return i
        u[i], v[i] = tuple(rng.uniform(-reach, reach, 2)), tuple(rng.uniform(-reach, reach, 2))
        thr[i], leaf[i] = rng.uniform(-0.5, 0.5), -1
        left[i] = node(level + 1)
        right[i] = node(level + 1)
        return i

    for _ in range(trees):
        roots.append(node(0))
    n_leaves = sum(x >= 0 for x in leaf)
    dist = rng.dirichlet(np.full(classes, 0.3), n_leaves).astype(np.float16)
    return Forest(
        u=np.array(u), v=np.array(v), threshold=np.array(thr), left=np.array(left),
        right=np.array(right), leaf=np.array(leaf), leaf_dist=dist, roots=np.array(roots),
        class_names=tuple(f"c{k}" for k in range(classes)), camera=CAMERA,
    )  # fmt: skip


def random_frames(batch: int, seed: int, h: int = 30, w: int = 40):
    """(B, H, W) float32 depth (1.5-3.5 m, holes, NaN outside the person) and a person mask."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    depth = rng.uniform(1.5, 3.5, (batch, h, w)).astype(np.float32)
    mask = np.zeros((batch, h, w), bool)
    for b in range(batch):
        cy, cx = rng.uniform(0.3, 0.7) * h, rng.uniform(0.3, 0.7) * w
        mask[b] = ((yy - cy) / (0.4 * h)) ** 2 + ((xx - cx) / (0.3 * w)) ** 2 < 1
    mask[:, 0, :] = True  # person pixels on the border: probes leave the image at once
    depth[rng.random(depth.shape) < 0.05] = 0.0  # no reading
    depth[~mask & (rng.random(depth.shape) < 0.1)] = np.nan  # garbage outside the person
    return torch.from_numpy(depth), torch.from_numpy(mask)


def walk_inputs(forest: Forest, depth: torch.Tensor, mask: torch.Tensor):
    valid = mask & (depth > 0) & torch.isfinite(depth)
    return traversal_table(forest), torch.nonzero(valid), valid


def torch_walk(forest, depth, mask, scale=(1.0, 1.0), compact=True, posteriors=False):
    table, pix, valid = walk_inputs(forest, depth, mask)
    t = torch.from_numpy(table)
    roots = torch.from_numpy(forest.roots.astype(np.int64))
    is_leaf = torch.from_numpy(forest.left < 0) if compact else None
    args = (forest.max_depth, forest.background_m, depth, valid, pix, scale, is_leaf)
    if posteriors:
        dist = torch.from_numpy(forest.leaf_dist.astype(np.float32))
        return walk_posteriors(t, roots, dist, *args).numpy()
    return walk_leaf_rows(t, roots, *args).numpy()


def kernel_walk(forest, depth, mask, scale=(1.0, 1.0), posteriors=False):
    kernel = pytest.importorskip("depthmocap.shared.forest_kernel")
    table, pix, valid = walk_inputs(forest, depth, mask)
    args = (forest.max_depth, forest.background_m, depth.numpy(), valid.numpy(), pix.numpy())
    if posteriors:
        dist = forest.leaf_dist.astype(np.float32)
        return kernel.walk_posteriors(table, forest.roots, dist, *args, scale)
    return kernel.walk_leaf_rows(table, forest.roots, *args, scale)


def test_compaction_does_not_change_the_torch_walk():
    forest = random_forest(3, 10, seed=1)
    depth, mask = random_frames(2, 1)
    assert np.array_equal(
        torch_walk(forest, depth, mask), torch_walk(forest, depth, mask, compact=False)
    )


@pytest.mark.parametrize("trees", [1, 2, 3, 5])
def test_kernel_reaches_the_torch_leaves_and_posteriors(trees):
    forest = random_forest(trees, 9, seed=trees)
    depth, mask = random_frames(3, trees)  # a batch of three frames
    rows = kernel_walk(forest, depth, mask)
    assert rows.shape == (int((mask & (depth > 0)).sum()), trees) and rows.dtype == np.int64
    assert np.array_equal(rows, torch_walk(forest, depth, mask))
    post = kernel_walk(forest, depth, mask, posteriors=True)
    ref = torch_walk(forest, depth, mask, posteriors=True)
    assert post.dtype == np.float32 and np.array_equal(post, ref)  # bit for bit
    assert len(np.unique(rows)) > 20  # the frames exercise many paths


def test_probes_off_the_image_and_camera_scaling():
    # Offsets up to 2000 pixel*metres: most probes land far outside the 40x30 image.
    forest = random_forest(3, 8, seed=5, reach=2000.0)
    depth, mask = random_frames(2, 5)
    for scale in [(1.0, 1.0), (2.0, 0.5), (0.37, 1.9)]:
        ref = torch_walk(forest, depth, mask, scale)
        assert np.array_equal(kernel_walk(forest, depth, mask, scale), ref)
        post = kernel_walk(forest, depth, mask, scale, posteriors=True)
        assert np.array_equal(post, torch_walk(forest, depth, mask, scale, posteriors=True))


def test_batch_equals_frames_one_by_one():
    forest = random_forest(3, 10, seed=7)
    depth, mask = random_frames(4, 7, h=60, w=80)
    whole = kernel_walk(forest, depth, mask, posteriors=True)
    single = np.concatenate(
        [kernel_walk(forest, depth[i : i + 1], mask[i : i + 1], posteriors=True) for i in range(4)]
    )
    assert len(whole) > 3000 and np.array_equal(whole, single)
    assert np.array_equal(whole, torch_walk(forest, depth, mask, posteriors=True))


def test_no_person_pixels():
    forest = random_forest(3, 6, seed=2)
    depth, _ = random_frames(2, 2)
    empty = torch.zeros_like(depth, dtype=torch.bool)
    assert kernel_walk(forest, depth, empty).shape == (0, 3)
    assert kernel_walk(forest, depth, empty, posteriors=True).shape == (0, 20)


def test_single_leaf_trees_and_fewer_levels_than_the_depth():
    kernel = pytest.importorskip("depthmocap.shared.forest_kernel")
    forest = random_forest(2, 7, seed=3)
    depth, mask = random_frames(1, 3)
    table, pix, valid = walk_inputs(forest, depth, mask)
    t, roots = torch.from_numpy(table), torch.from_numpy(forest.roots.astype(np.int64))
    for levels in (0, 1, 3):  # stops where the torch walk stops
        ref = walk_leaf_rows(t, roots, levels, 10.0, depth, valid, pix).numpy()
        args = (levels, 10.0, depth.numpy(), valid.numpy(), pix.numpy())
        assert np.array_equal(kernel.walk_leaf_rows(table, forest.roots, *args), ref)
    stumps = random_forest(3, 0, seed=4)  # every tree is one leaf
    assert stumps.max_depth == 0
    rows = kernel_walk(stumps, depth, mask)
    assert np.array_equal(rows, torch_walk(stumps, depth, mask)) and (rows == [0, 1, 2]).all()

"""The pixel classes of :func:`runtime.tracker.regions.classify` as one compiled pass (numba):
the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`~runtime.tracker.regions.classify` imports it lazily and keeps its torch code for GPUs,
autograd and where numba is missing.

Why: the split into G, B1, B2 and B3 is a dozen elementwise ops on (B, H, W) images every
Gauss-Newton iteration, 0.3-0.4 ms for a batch of starts; here one pass writes all five masks
and the depth difference with the same float32 operations (the gate compared in float32, as
torch casts a Python scalar to the tensor's dtype): the same regions, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["classify_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _classify(rendered, valid, silhouette, obs_depth, render_depth, gate, occlusion, good, b1,
              front, behind, b3, diff):  # fmt: skip  # pragma: no cover - compiled
    nb, h, w = rendered.shape
    g = gate[0]
    shared = valid.shape[0] == 1  # one observed frame for every pose
    for b in range(nb):
        o = 0 if shared else b
        for v in range(h):
            for u in range(w):
                r, ok = rendered[b, v, u], valid[o, v, u]
                d = obs_depth[o, v, u] - render_depth[b, v, u]
                diff[b, v, u] = d
                both = r & ok
                good[b, v, u] = both & ((abs(d) <= g) | (not occlusion))
                front[b, v, u] = both & (d > g) & occlusion
                behind[b, v, u] = both & (d < -g) & occlusion
                b1[b, v, u] = r & (not silhouette[o, v, u])
                b3[b, v, u] = ok & (not r)


def classify_cpu(
    rendered: torch.Tensor,
    valid: torch.Tensor,
    silhouette: torch.Tensor,
    obs_depth: torch.Tensor,
    render_depth: torch.Tensor,
    gate_m: float,
    occlusion: bool,
) -> tuple[torch.Tensor, ...]:
    """G, B1, B2 front, B2 behind, B3 (B, H, W) bool and the depth difference (B, H, W) for
    CPU (B, H, W) maps (the observed ones may be stride-0 views of one frame) and float32
    depths."""
    shape = rendered.shape
    masks = [np.empty(shape, np.bool_) for _ in range(5)]
    diff = np.empty(shape, np.float32)
    observed = [valid, silhouette, obs_depth]
    if all(t.stride(0) == 0 for t in observed):  # a batch of starts on one frame
        observed = [t[:1] for t in observed]
    valid, silhouette, obs_depth = (np.ascontiguousarray(t.numpy()) for t in observed)
    _classify(
        np.ascontiguousarray(rendered.numpy()), valid, silhouette, obs_depth,
        np.ascontiguousarray(render_depth.numpy()), np.array([gate_m], np.float32),
        bool(occlusion), *masks, diff,
    )  # fmt: skip
    return (*(torch.from_numpy(m) for m in masks), torch.from_numpy(diff))

"""Step 1 of person segmentation: the depth gate (readings inside the configured range)."""

from __future__ import annotations

import numpy as np
import torch

from .config import SegmentationConfig

__all__ = ["depth_valid_mask", "valid_np"]


def depth_valid_mask(depth_m: torch.Tensor, cfg: SegmentationConfig) -> torch.Tensor:
    """(B, H, W) bool: finite depth inside the configured range (NaN and 0 are invalid)."""
    return torch.isfinite(depth_m) & (depth_m >= cfg.min_depth_m) & (depth_m <= cfg.max_depth_m)


def valid_np(depth: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """Numpy twin of :func:`depth_valid_mask` (comparisons with NaN are False)."""
    return (depth >= cfg.min_depth_m) & (depth <= cfg.max_depth_m)

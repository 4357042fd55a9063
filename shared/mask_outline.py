"""Regions of a mask that reach its outline: what the person/clutter filter may take out.

Furniture the segmentation left attached to a person lies beyond them, so in the image it
reaches the silhouette's edge; a patch inside the silhouette is the body, whatever a per-pixel
classifier thinks of it (``runtime.segmentation.clutter``, and the threshold's evaluation in
``train.evaluation.clutter_threshold``).
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["mask_outline", "reaching_outline"]


def mask_outline(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the ``mask`` pixels with a 4-neighbour outside it (image borders count
    as outside)."""
    p = np.pad(np.asarray(mask, dtype=bool), 1)
    inner = p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
    return p[1:-1, 1:-1] & ~inner


def reaching_outline(region: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The connected parts (8-connected) of ``region`` that touch the outline of ``mask``
    (mask pixels with a 4-neighbour outside it, image borders included): (H, W) or (B, H, W)
    bool, like both inputs, on their device."""
    import cv2

    single = region.dim() == 2
    reg = region.cpu().numpy()[None] if single else region.cpu().numpy()
    msk = mask.cpu().numpy()[None] if single else mask.cpu().numpy()
    out = np.zeros_like(reg)
    for i in range(len(reg)):
        if not reg[i].any():
            continue
        outline = mask_outline(msk[i])
        _, labels = cv2.connectedComponents(reg[i].astype(np.uint8), connectivity=8)
        touching = np.unique(labels[reg[i] & outline])
        out[i] = np.isin(labels, touching[touching > 0])
    result = torch.from_numpy(out[0] if single else out)
    return result.to(region.device)

"""A batch of images as one 2-D canvas, so that OpenCV filters and labels all images in one call."""

from __future__ import annotations

import numpy as np

__all__ = ["Canvas"]


class Canvas:
    """The batch as one 2-D image for OpenCV: each (H, W) image sits below ``pad`` blank rows
    and between ``pad`` blank columns, so filters of radius ``pad`` and 4-neighbour look-ups
    at flat index +-1, +-width never mix images (blank = no reading)."""

    def __init__(self, b: int, h: int, w: int, pad: int):
        self.b, self.h, self.w, self.pad = b, h, w, pad
        self.shape = (pad + b * (h + pad), w + 2 * pad)

    def images(self, canvas: np.ndarray) -> np.ndarray:
        """(B, H, W) view of the images on a canvas."""
        p = self.pad
        return canvas[p:].reshape(self.b, self.h + p, -1)[:, : self.h, p : p + self.w]

    def place(self, images: np.ndarray) -> np.ndarray:
        """A blank canvas with the (B, H, W) ``images`` on it."""
        canvas = np.zeros(self.shape, dtype=images.dtype)
        self.images(canvas)[:] = images
        return canvas

    def image_of(self, labels: np.ndarray, comp_pixels: np.ndarray) -> np.ndarray:
        """(count,) batch index of each component of a label canvas (0 for label 0)."""
        if self.b == 1:
            return np.zeros(len(comp_pixels), dtype=np.intp)
        rows = np.clip((np.arange(self.shape[0]) - self.pad) // (self.h + self.pad), 0, None)
        index = np.broadcast_to(rows[:, None], self.shape).reshape(-1)
        # Every pixel of a component lies in one image: the mean index is that image's.
        total = np.bincount(labels.reshape(-1), index, minlength=len(comp_pixels))
        return np.rint(total / np.maximum(comp_pixels, 1)).astype(np.intp)

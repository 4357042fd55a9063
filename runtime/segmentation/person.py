"""The person mask: the steps of :mod:`runtime.segmentation` in order (numpy/OpenCV), and
:func:`segment_person`, the torch-facing entry point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics

from .canvas import Canvas
from .components import (
    Components,
    box_sizes,
    boxes,
    join_nearby_parts,
    occluded_by_large,
    plausible_size,
)
from .config import SegmentationConfig
from .depth_range import valid_np
from .floor import remove_floor
from .selection import component_solidity, person_scores

__all__ = ["SegmentationMemory", "segment_person", "segment_person_in_stream"]


@dataclass
class SegmentationMemory:
    """What one frame's segmentation leaves for the next frame of the same stream.

    Attributes:
        floor: the floor removed (normal (B, 3), centre (B, 3), found (B,)), or None.
        mask: (B, H, W) bool, the person found.
    """

    floor: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    mask: np.ndarray


def _segment_np(
    depth: np.ndarray,
    intr: Intrinsics,
    cfg: SegmentationConfig,
    memory: SegmentationMemory | None = None,
) -> tuple[np.ndarray, SegmentationMemory]:
    """:func:`segment_person` on (B, H, W) float32 metres in numpy/OpenCV -> (B, H, W) bool,
    and what the next frame of a stream needs to know (:class:`SegmentationMemory`)."""
    import cv2

    b, h, w = depth.shape
    if memory is not None and memory.mask.shape != (b, h, w):
        memory = None  # another batch or image size: nothing carries over
    valid = valid_np(depth, cfg)
    z_img = np.where(valid, depth, np.float32(0.0))
    floor = None
    if cfg.remove_floor:
        valid, floor = remove_floor(
            z_img, valid, intr, cfg, None if memory is None else memory.floor
        )

    r = max(cfg.merge_radius_px, 0)
    cv = Canvas(b, h, w, max(r, 1))
    valid = cv.place(valid)
    z = np.where(valid, cv.place(z_img), np.float32(0.0))
    zf, width = z.reshape(-1), cv.shape[1]

    # Cut the far side of depth discontinuities: a 4-neighbour nearer by more than the jump
    # (the nearest neighbour is a cross-shaped erosion; where a neighbour is unusable the pixel
    # stays: silhouettes against "no reading" are not cuts).
    z2 = z * z
    jump = cfg.edge_jump_m + cfg.edge_jump_per_m2 * z2
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    nearest = cv2.erode(np.where(valid, z, np.float32(np.inf)), cross)
    cut = (z - nearest > jump) & valid
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        (valid & ~cut).view(np.uint8), connectivity=4, ltype=cv2.CV_32S
    )
    labels = labels.astype(np.intp)  # bincount and fancy indexing want intp
    lf = labels.reshape(-1)

    # Per-component metric statistics; label 0 (background) is never chosen.
    # Metric area each pixel sees, facing the camera: z^2 / (fx fy).
    comp_pixels = np.bincount(lf, minlength=count)
    comp_area = np.bincount(lf, z2.reshape(-1), minlength=count) / (intr.fx * intr.fy)
    comp_depth = np.bincount(lf, zf, minlength=count) / np.maximum(comp_pixels, 1)
    image_of = cv.image_of(labels, comp_pixels)
    extent_box = boxes(z, labels, count, cv, intr)

    # Cut pixels and their 4 neighbours: what is seen behind what, and where the person's
    # own self-occlusion edges are.
    cut_px = np.flatnonzero(cut)
    nb = cut_px[:, None] + np.array([-width, width, -1, 1])  # (M, 4), never off the canvas
    lab_nb, z_nb = lf[nb], zf[nb]
    step = zf[cut_px, None] - z_nb
    jump_c = jump.reshape(-1)[cut_px, None]

    behind = occluded_by_large(lab_nb, step, jump_c, comp_area, count, cfg.occluder_min_area_m2)
    plausible = (
        ~behind & (comp_area >= cfg.min_area_m2) & plausible_size(box_sizes(extent_box), cfg)
    )
    plausible[0] = False
    # Which plausible component is the person: by area, shape and continuity (.selection).
    cand = np.flatnonzero(plausible)
    previous_share = np.zeros(len(cand))
    if memory is not None:
        was_person = np.bincount(lf, cv.place(memory.mask).reshape(-1), minlength=count)
        previous_share = was_person[cand] / np.maximum(comp_pixels[cand], 1)
    score = np.full(count, -1.0)
    score[cand] = person_scores(
        comp_area[cand],
        component_solidity(labels, stats, cand, cv2, cfg.solidity_erosion_px),
        previous_share,
        cfg,
    )
    per_image = np.where(image_of[None] == np.arange(b)[:, None], score[None], -1.0)  # (B, C)
    best = per_image.argmax(1)
    in_person = np.zeros(count, dtype=bool)
    in_person[best[per_image[np.arange(b), best] > 0]] = True
    comps = Components(labels, comp_pixels, comp_depth, comp_area, extent_box, image_of)
    in_person = join_nearby_parts(in_person, comps, b, cfg, cv2)
    mask = in_person[labels]

    # Add back cut pixels that join the person at a smooth step (self-occlusion inside it).
    smooth = (mask.reshape(-1)[nb] & (np.abs(step) <= jump_c)).any(1)
    mask.reshape(-1)[cut_px[smooth]] = True
    mask = cv.images(mask)
    return mask, SegmentationMemory(floor, mask.copy())


def segment_person(
    depth_m: torch.Tensor,
    intr: Intrinsics,
    cfg: SegmentationConfig | None = None,
    memory: SegmentationMemory | None = None,
) -> torch.Tensor:
    """Mask of the person in depth frames (steps: :mod:`runtime.segmentation`).

    Runs on the CPU in numpy/OpenCV whatever the input device (single frames are far too
    small for a GPU to pay off); the mask comes back on the input's device. For the frames of
    a stream use :class:`~runtime.segmentation.segmenter.PersonSegmenter`, which carries the
    floor and the person from frame to frame.

    Args:
        depth_m: (H, W) or (B, H, W) metric depth; 0 or NaN where there is no reading.
        intr: intrinsics of the H x W images.
        cfg: settings (defaults when None).
        memory: the previous frame's :class:`SegmentationMemory` (the same batch size), or
            None for images on their own.
    Returns:
        bool mask of the same shape as ``depth_m``; all False where no person is found.
    """
    return segment_person_in_stream(depth_m, intr, cfg, memory)[0]


def segment_person_in_stream(
    depth_m: torch.Tensor,
    intr: Intrinsics,
    cfg: SegmentationConfig | None = None,
    memory: SegmentationMemory | None = None,
) -> tuple[torch.Tensor, SegmentationMemory]:
    """:func:`segment_person`, also returning the memory to pass with the next frame."""
    cfg = cfg or SegmentationConfig()
    single = depth_m.ndim == 2
    depth = depth_m[None] if single else depth_m
    if depth.ndim != 3 or depth.shape[-2:] != (intr.height, intr.width):
        raise ValueError(
            f"depth must be (H, W) or (B, H, W) with H x W = {intr.height}x{intr.width}, "
            f"got {tuple(depth_m.shape)}"
        )
    depth_np = np.ascontiguousarray(depth.detach().to("cpu", torch.float32).numpy())
    mask_np, memory = _segment_np(depth_np, intr, cfg, memory)
    mask = torch.from_numpy(mask_np.copy()).to(depth_m.device)
    return (mask[0] if single else mask), memory

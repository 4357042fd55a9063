"""The person segmentation of a stream: :func:`segment_person` frame after frame, carrying
the floor and the person over from one frame to the next (:mod:`.selection`, :mod:`.floor`),
then, with ``clutter_model``, the furniture left attached taken out (:mod:`.clutter`)."""

from __future__ import annotations

import torch
from depthmocap.shared.camera import Intrinsics

from .clutter import ClutterFilter
from .config import SegmentationConfig
from .person import SegmentationMemory, segment_person_in_stream

__all__ = ["PersonSegmenter"]


class PersonSegmenter:
    """Segments the frames of one stream, in order.

    Call it as ``segmenter(depth_m, intrinsics)`` (the signature of :func:`segment_person`);
    :meth:`reset` forgets the previous frame (a cut, another camera, a new person).
    """

    def __init__(self, cfg: SegmentationConfig | None = None) -> None:
        self.cfg = cfg or SegmentationConfig()
        self._memory: SegmentationMemory | None = None
        self._intrinsics: Intrinsics | None = None
        self._clutter = (
            ClutterFilter(self.cfg.clutter_model, self.cfg.clutter_threshold)
            if self.cfg.clutter_model
            else None
        )

    def __call__(self, depth_m: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
        """(H, W) metres -> (H, W) bool person mask on the input's device."""
        if intr != self._intrinsics:  # another camera: nothing carries over
            self.reset()
            self._intrinsics = intr
        mask, self._memory = segment_person_in_stream(depth_m, intr, self.cfg, self._memory)
        if self._clutter is not None:
            mask = self._clutter(depth_m, mask, intr)
        return mask

    @property
    def floor(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The floor removed from the last frame: (unit up normal (3,), a point on it (3,)),
        camera frame, float64; None when no floor was found (or no frame seen)."""
        floor = None if self._memory is None else self._memory.floor
        if floor is None or not bool(floor[2][0]):
            return None
        return torch.as_tensor(floor[0][0]), torch.as_tensor(floor[1][0])

    def reset(self) -> None:
        self._memory = None

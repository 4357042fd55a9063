"""One depth frame, prepared once and shared by everything that estimates a pose from it.

``runtime-track`` reads a :class:`~runtime.streams.base.DepthFrame` (uint16 millimetres),
converts it to metres, segments the person, and hands the resulting :class:`Frame` to the
estimator. Whatever else a frame needs is computed on first use and kept on the frame, so that
the tracker, every refit of the arm search, the detector's refinement and the observed-joint
flags all read the same values instead of each re-preparing them:

- the part labels of a label source (the forest, or a recording's ground truth):
  :meth:`Frame.labels`;
- a tracker's working-resolution observation (window, pooling, points, distance transform):
  :meth:`Frame.observation`.

A frame belongs to one stream position; nothing on it is valid for another frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics

if TYPE_CHECKING:
    from depthmocap.runtime.streams.base import DepthFrame
    from depthmocap.runtime.tracker.observation import Observation
    from depthmocap.runtime.tracker.tracker import Tracker

__all__ = ["Frame", "FrameError", "LabelSource", "depth_mm_to_metres"]

# A frame -> its (H, W) int64 part labels (shared.labels classes, 0 = background), or the
# labels with each one's posterior ((H, W) float; the forest's).
LabelSource = Callable[["Frame"], "torch.Tensor | tuple[torch.Tensor, torch.Tensor]"]


class FrameError(ValueError):
    """Frame data whose parts do not fit together (shapes)."""


def depth_mm_to_metres(depth_mm: np.ndarray, device: str | torch.device = "cpu") -> torch.Tensor:
    """(H, W) millimetres (uint16, or float with NaN / inf / negatives) -> float32 metres on
    ``device``, 0 = no reading. The one conversion every part of the runtime uses."""
    depth = np.asarray(depth_mm)
    if depth.dtype.kind == "f":
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    return torch.from_numpy(depth.astype(np.float32)).to(device) * 1e-3


@dataclass(eq=False)
class Frame:
    """A depth frame in metres with the person's mask, and what is derived from them.

    Attributes:
        index: frame number in the source (ground truth and labels are matched by it).
        time: seconds since the start of the source.
        depth_m: (H, W) float32 metres, 0 = no reading.
        mask: (H, W) bool, the person's pixels (from the segmentation).
        intrinsics: the camera of this image.
        depth_mm: the source's (H, W) millimetres, for drawing overlays; None if not kept.
    """

    index: int
    time: float
    depth_m: torch.Tensor
    mask: torch.Tensor
    intrinsics: Intrinsics
    depth_mm: np.ndarray | None = None
    _labels: dict = field(default_factory=dict, repr=False)
    _label_confidence: dict = field(default_factory=dict, repr=False)
    _observations: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.depth_m.dim() != 2 or self.mask.shape != self.depth_m.shape:
            raise FrameError(
                f"depth and mask must both be (H, W), got {tuple(self.depth_m.shape)} and "
                f"{tuple(self.mask.shape)}"
            )
        if self.mask.dtype != torch.bool or self.mask.device != self.depth_m.device:
            self.mask = self.mask.to(device=self.depth_m.device, dtype=torch.bool)

    @classmethod
    def from_depth(
        cls,
        frame: DepthFrame,
        mask: np.ndarray | torch.Tensor | None = None,
        device: str | torch.device = "cpu",
        segment: Callable[[torch.Tensor, Intrinsics], torch.Tensor] | None = None,
    ) -> Frame:
        """A :class:`Frame` of a stream's ``frame``: the person's ``mask`` as given, or from
        ``segment(depth_m, intrinsics)`` (e.g. ``runtime.segmentation.segment_person``)."""
        depth = depth_mm_to_metres(frame.depth_mm, device)
        if mask is None:
            if segment is None:
                raise FrameError("a frame needs a person mask or a segmentation function")
            mask = segment(depth, frame.intrinsics)
        mask = torch.as_tensor(np.asarray(mask) if not torch.is_tensor(mask) else mask)
        return cls(frame.index, frame.time, depth, mask, frame.intrinsics, frame.depth_mm)

    @property
    def device(self) -> torch.device:
        return self.depth_m.device

    @property
    def has_person(self) -> bool:
        """Whether the segmentation found anyone: a frame without is lost as it stands."""
        return bool(self.mask.any())

    def drop_pixels(self, drop: torch.Tensor) -> None:
        """Take ``drop`` (H, W) bool out of the person's mask (and their labels out of the
        labels computed so far), before any observation is made of the frame.

        Raises:
            FrameError: an observation was already made (it would still hold them).
        """
        if self._observations:
            raise FrameError(f"frame {self.index}: pixels dropped after an observation was made")
        keep = ~drop.to(device=self.device, dtype=torch.bool)
        self.mask = self.mask & keep
        for source, labels in self._labels.items():
            self._labels[source] = labels * keep

    def labels(self, source: LabelSource) -> torch.Tensor:
        """(H, W) int64 part labels from ``source``, computed on the first call per source."""
        if source not in self._labels:
            labels = source(self)
            confidence = None
            if isinstance(labels, tuple):
                labels, confidence = labels
            for name, image in (("labels", labels), ("label confidence", confidence)):
                if image is not None and image.shape != self.mask.shape:
                    raise FrameError(
                        f"frame {self.index}: {name} {tuple(image.shape)} do not match the "
                        f"frame {tuple(self.mask.shape)}"
                    )
            self._labels[source] = labels.to(device=self.device, dtype=torch.long)
            if confidence is not None:
                self._label_confidence[source] = confidence.to(self.device, torch.float32)
        return self._labels[source]

    def label_confidence(self, source: LabelSource) -> torch.Tensor | None:
        """(H, W) float32 posterior of each of ``source``'s labels (:meth:`labels`), or None
        when the source gives none (ground-truth labels)."""
        self.labels(source)
        return self._label_confidence.get(source)

    def observation(
        self,
        tracker: Tracker,
        labels: torch.Tensor | None = None,
        label_confidence: torch.Tensor | None = None,
    ) -> Observation:
        """``tracker``'s working-resolution observation of this frame, computed once per
        tracker and per label image (``labels``: this frame's part labels for the tracker's
        label term, or None; ``label_confidence``: their posteriors, for the tracker's label
        gate, or None)."""
        if not tracker.cfg.use_labels:
            labels = None  # the tracker would drop them: the same observation either way
        if labels is None or tracker.cfg.label_min_posterior <= 0:
            label_confidence = None  # likewise
        key = (id(tracker), *(None if x is None else id(x) for x in (labels, label_confidence)))
        if key not in self._observations:
            # Keyed by identity: keep the tracker and the images alive with their entry.
            obs = tracker.observe(self.depth_m, self.mask, labels, label_confidence)
            self._observations[key] = (tracker, labels, label_confidence, obs)
        return self._observations[key][-1]

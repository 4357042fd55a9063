"""Furniture out of the person's mask: the person/clutter forest (``segmentation.clutter_model``).

Where a chair, a table or a cupboard touches the person at about the same depth, the depth
cut of :mod:`.person` cannot separate them: on real Kinect depth the seat of the chair a
person sits on stays in the mask, and the tracker bends the hips to explain it
(``docs/real_data.md``). A small forest, trained on rendered people with furniture drawn flush
with them (``train/synth/props.py``, ``make train-clutter``), reads each mask pixel's
neighbourhood with the body-part forest's depth features and says person or clutter; pixels
whose clutter posterior (smoothed over :data:`~shared.labels.CLUTTER_SMOOTH_WINDOW`
neighbours at the same depth, as the part labels are) reaches the threshold leave the mask,
if they are connected to the mask's outline: furniture the segmentation left attached lies
beyond the person and so reaches the silhouette's edge (a seat beside the hips, a table
beside the body, the legs of a chair between the person's legs), while a patch of the body
that the forest doubts (a thigh seen end-on behind a torso bent forwards) lies inside it and
stays.
"""

from __future__ import annotations

from pathlib import Path

import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import load_forest
from depthmocap.shared.labels import CLUTTER_CLASSES, CLUTTER_SMOOTH_WINDOW
from depthmocap.shared.mask_outline import reaching_outline
from depthmocap.shared.resources import MODELS_DIR

__all__ = ["ClutterFilter", "clutter_model_path", "reaching_outline"]

_CLUTTER = CLUTTER_CLASSES.index("clutter")


def clutter_model_path(name: str) -> Path:
    """``name`` as given when it names an existing file or a folder, else in ``models/``."""
    path = Path(name)
    return path if path.exists() or path.parent != Path(".") else MODELS_DIR / path


class ClutterFilter:
    """Drops the pixels the person/clutter forest calls clutter from a person's mask.

    Args:
        path: the forest (``forest.npz`` format, classes
            :data:`~shared.labels.CLUTTER_CLASSES`); a bare name is looked up in ``models/``.
        threshold: a pixel whose clutter posterior reaches this leaves the mask.
    Raises:
        ForestFormatError: a missing or unreadable file, or a forest of other classes.
    """

    def __init__(self, path: str | Path, threshold: float = 0.7) -> None:
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"clutter_threshold must be in (0, 1], not {threshold}")
        self.forest = load_forest(clutter_model_path(str(path)), CLUTTER_CLASSES)
        self.threshold = threshold
        self._classifiers: dict = {}

    def _classifier(self, intr: Intrinsics, device: torch.device):
        from depthmocap.runtime.forest.inference import ForestClassifier

        key = (intr.fx, intr.fy, str(device))
        if key not in self._classifiers:
            self._classifiers[key] = ForestClassifier(
                self.forest, device=device, intrinsics=intr, smooth_window=CLUTTER_SMOOTH_WINDOW
            )
        return self._classifiers[key]

    def clutter(self, depth_m: torch.Tensor, mask: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
        """(H, W) or (B, H, W) bool: the ``mask`` pixels called clutter and connected to the
        mask's outline."""
        posteriors = self._classifier(intr, depth_m.device).posteriors(depth_m, mask)
        called = (posteriors.select(-3, _CLUTTER) >= self.threshold).to(mask.device) & mask
        return reaching_outline(called, mask)

    def __call__(self, depth_m: torch.Tensor, mask: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
        """``mask`` without the clutter (same shape and device)."""
        if not bool(mask.any()):
            return mask
        return mask & ~self.clutter(depth_m, mask, intr)

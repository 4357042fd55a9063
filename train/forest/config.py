"""Training configuration of the randomized decision forest (presets in configs/forest*.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from depthmocap.shared.config import field_doc
from depthmocap.shared.forest_format import DEFAULT_BACKGROUND_M

__all__ = ["ForestConfig"]


@dataclass
class ForestConfig:
    """How ``train-forest`` grows the forest (see ``train/forest/__init__.py`` for the method)."""

    trees: int = field_doc(3, "number of trees")
    max_depth: int = field_doc(20, "maximum depth (split levels on a root-to-leaf path)")
    min_samples: int = field_doc(
        8, "minimum training pixels in a child: nodes with fewer than twice this stay leaves"
    )
    min_gain: float = field_doc(1e-4, "minimum Shannon information gain (nats) to split a node")
    feature_pool: int = field_doc(
        768,
        "offset pairs (u, v) drawn per tree; their features are computed once for every training "
        "pixel of the tree and the candidates of each level are drawn from this pool",
    )
    candidates_per_node: int = field_doc(
        192, "offset pairs evaluated at every node (a fresh random subset of the pool per level)"
    )
    thresholds_per_candidate: int = field_doc(
        32,
        "thresholds per offset pair: the edges of this many quantile bins of the feature "
        "(at most 256); deep levels with many small nodes merge adjacent bins",
    )
    pixels_per_frame: int = field_doc(200, "training pixels drawn from each person per frame")
    frames_per_tree: float = field_doc(
        0.5, "fraction of the training frames each tree sees (a fresh random subset per tree)"
    )
    class_balanced: bool = field_doc(
        True,
        "draw pixels with probability proportional to 1 / (class pixel frequency)^"
        "balance_power, so that small parts (neck, hands) are not starved",
    )
    balance_power: float = field_doc(
        0.5, "exponent of the class-balancing weights (1 = fully balanced, 0 = uniform)"
    )
    offset_max_m: float = field_doc(
        0.3,
        "largest probe displacement in the scene (m) along each image axis; stored offsets are "
        "pixel*metres = metres * the training camera's focal length",
    )
    unary_fraction: float = field_doc(
        0.25, "fraction of offset pairs with v = 0, i.e. f = D(x + u/D(x)) - D(x)"
    )
    refit_pixels_per_frame: int = field_doc(
        0,
        "after growing, re-estimate the leaf distributions from this many class-balanced person "
        "pixels of every training frame (train/forest/refit.py); 0 = keep the grown ones",
    )
    refit_prior: float = field_doc(
        2.0, "weight, in pixels, of a leaf's grown distribution in its re-estimate"
    )
    background_m: float = field_doc(
        DEFAULT_BACKGROUND_M,
        "depth read by probes off the image, off the person, or on pixels without a reading (m)",
    )
    trees_per_pass: int = field_doc(
        0,
        "trees whose pixels are collected in one pass over the data (0 = all): fewer passes "
        "read the shards fewer times, more passes hold fewer (pixels x pool) byte matrices",
    )
    histogram_budget: int = field_doc(
        1 << 24, "largest (nodes x candidates x thresholds x classes) histogram built at once"
    )
    seed: int = field_doc(0, "random seed (frames, pixels, offsets, candidates)")
    device: Literal["auto", "cpu", "cuda"] = field_doc(
        "auto", "torch device for training: auto = CUDA when present, else CPU"
    )
    threads: int = field_doc(2, "torch CPU threads")

    def validate(self) -> None:
        """Raise ``ValueError`` on settings that cannot train a forest."""
        if self.trees < 1 or self.max_depth < 1 or self.min_samples < 1:
            raise ValueError("trees, max_depth and min_samples must be >= 1")
        if not 1 <= self.candidates_per_node <= self.feature_pool:
            raise ValueError("need 1 <= candidates_per_node <= feature_pool")
        if not 2 <= self.thresholds_per_candidate <= 256:
            raise ValueError("thresholds_per_candidate must be in [2, 256]")
        if self.pixels_per_frame < 1 or not 0.0 < self.frames_per_tree <= 1.0:
            raise ValueError("pixels_per_frame must be >= 1 and frames_per_tree in (0, 1]")
        if self.offset_max_m <= 0 or not 0.0 <= self.unary_fraction <= 1.0:
            raise ValueError("offset_max_m must be > 0 and unary_fraction in [0, 1]")
        if not 0.0 <= self.balance_power <= 1.0:
            raise ValueError("balance_power must be in [0, 1]")
        if not 0.0 < self.background_m < 32.0:
            raise ValueError("background_m must be in (0, 32) m (int16 millimetre features)")
        if self.refit_pixels_per_frame < 0 or self.refit_prior < 0:
            raise ValueError("refit_pixels_per_frame and refit_prior must be >= 0")
        if self.trees_per_pass < 0:
            raise ValueError("trees_per_pass must be >= 0")
        if self.threads < 1 or self.histogram_budget < 1:
            raise ValueError("threads and histogram_budget must be >= 1")

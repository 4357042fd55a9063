"""Training of the per-pixel body-part forest (Wei 2012 section 4.1; Shotton et al. 2011).

Features ``f = D(x + u/D(x)) - D(x + v/D(x))`` on the segmented person's depth (everything
else, and everything off the image, reads a 10 m background constant); binary splits
``f > threshold``; Shannon information gain; trees grown breadth-first, a level at a time,
vectorized over pixels and candidates (torch; CUDA when present). Modules:

- :mod:`.config`: :class:`ForestConfig` (presets ``configs/forest.yaml``, ``forest_tiny.yaml``);
- :mod:`.features`: pixel sampling and depth-difference features;
- :mod:`.grow`: level-wise tree growing on quantile-binned features;
- :mod:`.trainer`: training set -> :class:`shared.forest_format.Forest`;
- :mod:`.predict`, :mod:`.evaluate`: accuracy and confusion matrix on labelled frames;
- :mod:`.onnx_export`: the classifier as an ONNX graph;
- :mod:`.train_cli` (``train-forest``), :mod:`.eval_cli` (``train-forest-eval``).
"""

from .config import ForestConfig
from .trainer import train_forest

__all__ = ["ForestConfig", "train_forest"]

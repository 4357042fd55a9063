"""Per-pixel body-part classification with a trained randomized forest (Wei 2012 section 4.1).

``ForestClassifier(load_forest(path), device)`` gives posteriors and labels of the pixels of a
person mask (torch on CPU/CUDA, or onnxruntime).
"""

from .inference import DEFAULT_MODEL, ForestClassifier, load_classifier, traverse

__all__ = ["DEFAULT_MODEL", "ForestClassifier", "load_classifier", "traverse"]

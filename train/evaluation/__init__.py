"""Evaluation of tracking results (Helten et al. 2013 section IV, Wei et al. 2012 section 7).

:mod:`.metrics` holds the pure metric functions and their definitions, :mod:`.result_io`
reads a result directory, :mod:`.evaluate` matches it with a recording's ground truth,
:mod:`.plot` draws the figure; ``train-eval`` (:mod:`train.evaluation.cli`) ties them together.
"""

from .evaluate import EvalConfig, Evaluation, EvaluationError, evaluate
from .result_io import ResultFileError, TrackingResult, load_result

__all__ = [
    "EvalConfig",
    "Evaluation",
    "EvaluationError",
    "evaluate",
    "ResultFileError",
    "TrackingResult",
    "load_result",
]

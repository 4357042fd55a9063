"""MAP tracker of Wei et al. 2012 section 3 (depth, extra depth, silhouette, prior terms)."""

from .config import TrackerConfig, TrackerConfigError
from .estimator import TrackerEstimator, create_estimator
from .tracker import FrameFit, Tracker, TrackerError, TrackResult, fit_frames, track_sequence

__all__ = [
    "TrackerConfig",
    "TrackerConfigError",
    "Tracker",
    "TrackResult",
    "TrackerError",
    "FrameFit",
    "fit_frames",
    "track_sequence",
    "TrackerEstimator",
    "create_estimator",
]

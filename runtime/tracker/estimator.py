"""Mode "tracker" of ``runtime-track``: the MAP tracker alone, for evaluating it (issue 5).

It has no detector, so it must be told where the person is at the start: ``config["initial_q"]``
(34,), which ``runtime-track`` takes from the input's ground truth (a recording made by
``train-synth --sequence``, or the demo). Each frame is then tracked from the previous two
poses; a frame without a person keeps the last pose and is reported lost.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import as_config
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

from .config import TrackerConfig
from .tracker import Tracker, TrackerError

__all__ = ["TrackerEstimator", "create_estimator"]


class TrackerEstimator:
    """The tracker behind the ``PoseEstimator`` protocol of :mod:`runtime.estimator`."""

    def __init__(self, tracker: Tracker, body: BodyShape, initial_q: np.ndarray):
        self.tracker = tracker
        self.body = body.to(torch.float64)
        self._prev = (torch.as_tensor(np.asarray(initial_q, dtype=np.float64)), None)

    def reset(self) -> None:
        """Nothing to forget: with no detector the tracker resumes from its last pose."""

    def estimate(self, frame):
        from depthmocap.runtime.estimator import PoseEstimate, observed_of

        q_prev, q_prev2 = self._prev
        res = self.tracker.fit(frame.observation(self.tracker), q_prev, q_prev2)
        q = res.q.detach().to("cpu", torch.float64)
        self._prev = (q, q_prev)
        joints = named_joint_positions(forward_kinematics(q[None], self.body))[0].numpy()
        errors = {**res.signals.as_errors(), "iterations": float(res.iterations)}
        return PoseEstimate(q.numpy(), joints, "tracked", errors, observed=observed_of(res))


def create_estimator(
    *,
    model_path: Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: Mapping[str, Any] | None = None,
) -> TrackerEstimator:
    """Mode "tracker": ``config`` holds ``initial_q`` plus any :class:`TrackerConfig` keys."""
    config = dict(config or {})
    initial_q = config.pop("initial_q", None)
    if initial_q is None:
        raise TrackerError(
            "mode 'tracker' starts from ground truth: the input needs a first-frame pose "
            "(a recording with groundtruth.npz, or 'demo'); use --mode hybrid otherwise"
        )
    cfg = as_config(TrackerConfig, config, "tracker config", TrackerError)
    del model_path  # the tracker alone needs no forest
    return TrackerEstimator(Tracker(body, intrinsics, cfg, device=device), body, initial_q)

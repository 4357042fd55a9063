"""Building a pose estimator from what a user names: device, body, model, preset and config.

Shared by ``runtime-track`` and the Python API (:class:`runtime.api.Tracker`), so both check
the same things in the same order and fail with the same one-line messages.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.config import ConfigError, load_settings, merged_settings
from depthmocap.shared.resources import CONFIGS_DIR

from .estimator import MODES_NEEDING_MODEL
from .presets import DEFAULT_PRESET, preset_settings

__all__ = [
    "AUTO_DEVICE",
    "POPULATION_BODY",
    "TrackError",
    "pick_device",
    "load_body",
    "check_model",
    "load_mode_config",
    "settings_for_body",
]


# The body tracked when none is given: the average measured skeleton of 100 random bodies of
# the training population (``python -m depthmocap.train.bodies.template_body``; also
# ``runtime-calibrate``'s template). Its proportions are where the reported joints are (the
# built-in ``BodyShape.default`` has rounded textbook ones: a chest 31% short for them), and the
# size search scales it to the person.
POPULATION_BODY = CONFIGS_DIR / "body_template.json"


class TrackError(ValueError):
    """Bad options or set-up for ``runtime-track`` (one line, shown as ``error: ...``)."""


# What "auto" runs on: the device the shipped hybrid is fastest on, as measured. On both GPUs
# lent so far the whole hybrid was slower on CUDA than on two CPU threads of the same machine
# (H200: demo median frame 65.5 vs 45.3 ms; H100: 133 vs 25.1 ms over five broad
# recordings), since a frame is thousands of small kernels and hundreds of host syncs
# (docs/results.md). Switch this to CUDA only once `scripts/gpu_check.sh` shows the GPU ahead.
AUTO_DEVICE = "cpu"


def pick_device(name: str) -> str:
    """ "auto" -> :data:`AUTO_DEVICE` (the CPU, measured faster than CUDA); "cuda" without a
    GPU is an error."""
    if name == "auto":
        return AUTO_DEVICE
    if name == "cuda" and not torch.cuda.is_available():
        raise TrackError("--device cuda: no CUDA device available (use --device cpu)")
    return name


def load_body(path: Path | None) -> BodyShape:
    """The body in ``path`` (a ``body.json``), or for None the population's average adult
    (:data:`POPULATION_BODY`)."""
    given = path is not None
    path = path if given else POPULATION_BODY
    try:
        return BodyShape.load(path)
    except FileNotFoundError:
        if not given:
            raise TrackError(
                f"the shipped population body is missing: {path} (reinstall depthmocap, or "
                "give --body)"
            ) from None
        raise TrackError(f"body file not found: {path}") from None
    except ValueError as err:
        raise TrackError(str(err)) from None


def check_model(path: Path, mode: str) -> None:
    """Fail early, before a camera is opened, on a missing or unreadable model."""
    if mode not in MODES_NEEDING_MODEL:
        return
    if not path.is_file():
        raise TrackError(
            f"model file not found: {path} (train one with `make train-forest` or pass --model)"
        )
    try:
        from depthmocap.shared.forest_format import load_forest_shared
        from depthmocap.shared.labels import PART_NAMES
    except ImportError:  # the estimator's own loader will check it
        return
    load_forest_shared(path, expected_classes=PART_NAMES)  # the estimator reuses what it read


def load_mode_config(
    path: Path | Mapping | None, preset: str | None = None, mode: str = "hybrid"
) -> dict:
    """The mode's settings: for the hybrid, the ``preset`` (default: the shipped system)
    with ``--config``'s YAML (or a mapping of the same shape) on top, key by key; for the
    other modes ``--config`` alone (:func:`shared.config.load_settings`; the values are
    checked by the mode itself)."""
    if preset is not None and mode != "hybrid":
        raise TrackError(f"--preset names hybrid settings; mode '{mode}' takes --config only")
    try:
        base = preset_settings(preset or DEFAULT_PRESET) if mode == "hybrid" else {}
        if path is None:
            return base
        overlay = dict(path) if isinstance(path, Mapping) else load_settings(path)
        return merged_settings(base, overlay)
    except ConfigError as err:
        raise TrackError(str(err)) from None


def settings_for_body(settings: dict, mode: str, body_given: bool) -> dict:
    """The hybrid's settings for a run with or without a body file: with one, the person's
    size is known and is not estimated (``body_scale`` off), and the output joints are the
    body's own (``joint_offsets`` off: they were fitted on the population body's joints)."""
    if mode != "hybrid" or not body_given:
        return settings
    return merged_settings(settings, {"body_scale": None, "joint_offsets": None})

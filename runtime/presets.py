"""The named settings of the hybrid that ship with the package (``runtime-track --preset``).

``shipped`` is what ``runtime-track`` runs with no options: the best configuration this project
has measured (``HybridConfig()``, spelled out in ``configs/hybrid.yaml``). ``wei2012`` is the
paper's (Wei, Zhang & Chai 2012: its switching thresholds, none of this project's additions),
for ablations. A preset file may start from another with ``extends: OTHER.yaml``; a user's
``--config FILE`` goes on top of the preset, key by key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from depthmocap.shared.config import ConfigError, load_settings
from depthmocap.shared.resources import CONFIGS_DIR

__all__ = ["DEFAULT_PRESET", "PRESETS", "Preset", "PresetError", "configs_dir", "preset_settings"]


class PresetError(ConfigError):
    """An unknown preset name, or a preset file that is missing or malformed."""


@dataclass(frozen=True)
class Preset:
    """A named settings file of the hybrid: ``file`` in the shipped configs folder."""

    name: str
    file: str
    description: str


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("shipped", "hybrid.yaml", "the best configuration measured (the default)"),
        Preset("wei2012", "wei2012.yaml", "Wei et al. 2012 as published, for ablations"),
    )
}
DEFAULT_PRESET = "shipped"


def configs_dir() -> Path:
    """The folder of the shipped presets and body template."""
    return CONFIGS_DIR


def preset_settings(name: str) -> dict:
    """The settings mapping of the preset ``name``.

    Raises:
        PresetError: unknown name (the message lists the known ones), or an unreadable file.
    """
    if name not in PRESETS:
        raise PresetError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    try:
        return load_settings(configs_dir() / PRESETS[name].file)
    except ConfigError as err:
        raise PresetError(f"preset '{name}': {err}") from None

"""Where the shipped data and the caches live, in a checkout and in an installed package alike.

The wheel maps the checkout's top-level folders into one package (``setup.py``): ``shared/`` is
installed as ``depthmocap/shared``, ``configs/`` as ``depthmocap/configs`` and ``models/`` as
``depthmocap/models``. The folders keep their relative places, so the same relative path finds
them in both layouts and no checkout is needed.
"""

from __future__ import annotations

import os
from pathlib import Path

# The checkout's root, or site-packages/depthmocap when installed.
PACKAGE_ROOT = Path(__file__).resolve().parents[1]
CONFIGS_DIR = PACKAGE_ROOT / "configs"
MODELS_DIR = PACKAGE_ROOT / "models"


def model_file(name: str | Path) -> Path:
    """The path of a model file setting: ``name`` itself when absolute, else under the shipped
    ``models/`` folder (the rule of every model file a preset names)."""
    path = Path(name)
    return path if path.is_absolute() else MODELS_DIR / path


def is_checkout() -> bool:
    """True when running from a source checkout (editable install or ``python -m``)."""
    return (PACKAGE_ROOT / "pyproject.toml").is_file()


def cache_root() -> Path:
    """Root of the writable caches: ``$DEPTHMOCAP_CACHE``; else ``<checkout>/.cache`` in a
    checkout, ``~/.cache/depthmocap`` when installed (site-packages may be read-only)."""
    env = os.environ.get("DEPTHMOCAP_CACHE")
    if env:
        return Path(env)
    if is_checkout():
        return PACKAGE_ROOT / ".cache"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "depthmocap"

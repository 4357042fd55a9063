"""Small JSON files the project ships and reads (joint offsets, joint confidence): written
atomically, read with one clear error for a missing or unreadable file."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["read_json_file", "write_json_file"]


def write_json_file(path: str | Path, data: dict) -> None:
    """Write ``data`` as indented JSON to ``path`` (atomically: a reader never sees half a
    file), creating its folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    tmp.replace(path)


def read_json_file(path: str | Path, what: str, error: type[Exception]) -> object:
    """The parsed JSON in ``path``.

    Raises:
        error: ``"PATH: no such WHAT file"`` or ``"PATH: not a readable WHAT file (...)"``.
    """
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise error(f"{path}: not a readable {what} file ({err})") from None

"""Fixtures of the benchmark tests."""

from __future__ import annotations

from pathlib import Path

import pytest


def _write_demo_recordings(root: Path, names: tuple[str, ...], frames: int = 2) -> None:
    from depthmocap.runtime.streams import open_stream
    from depthmocap.shared.recording import RecordingWriter

    for name in names:
        with open_stream("demo") as stream:
            first = [f for _, f in zip(range(frames), stream, strict=False)]
        with RecordingWriter(root / name, first[0].intrinsics, fps=30.0, source="t") as w:
            for f in first:
                w.write_frame(f.depth_mm)


@pytest.fixture(scope="session")
def write_demo_recordings():
    """``write(root, names, frames=2)``: recordings ``root/NAME`` of the demo person's first
    frames."""
    return _write_demo_recordings


@pytest.fixture(scope="module")
def two_demo_recordings(tmp_path_factory, write_demo_recordings) -> Path:
    """A folder of two 2-frame recordings of the demo person, ``a`` and ``b``."""
    root = tmp_path_factory.mktemp("recs")
    write_demo_recordings(root, ("a", "b"))
    return root

"""The README's Python API examples run as written (issue 35)."""

from __future__ import annotations

import re
from pathlib import Path

import depthmocap.runtime.track_cli as cli
import pytest
import torch

README = Path(__file__).resolve().parents[1] / "README.md"


def api_examples() -> list[str]:
    """The ```python blocks of the README's "Python API" section, in order."""
    text = README.read_text()
    section = text.split("\n## Python API\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_section_has_the_examples():
    blocks = api_examples()
    assert len(blocks) == 2
    assert "from depthmocap import Tracker, open_stream" in blocks[0]
    assert "read_poses(" in blocks[1] and "tracker.reset()" in blocks[1]


@pytest.mark.slow
def test_the_api_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    before = torch.get_num_threads()
    # The second example reads the result `make demo` leaves; make a short one there.
    assert cli.main(["-i", "demo", "-o", "out/demo/result", "--stop", "5", "-q"]) == 0
    torch.set_num_threads(before)
    for i, block in enumerate(api_examples()):
        exec(compile(block, f"README.md:python-block-{i}", "exec"), {"__name__": "__readme__"})
    printed = capsys.readouterr().out.splitlines()
    # Block 1 prints frames 0, 30 and 60 of the demo; block 2 one line.
    assert [line.split()[0] for line in printed[:3]] == ["0", "30", "60"]
    assert all(line.split()[1] in ("tracked", "detected") for line in printed[:3])
    assert printed[3].startswith("(5, 16, 3)")

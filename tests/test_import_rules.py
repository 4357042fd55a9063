"""The layering of DESIGN.md: runtime never imports train, shared imports neither, nothing but
the benchmarks imports bench (bench may use shared and runtime, not train), and the runtime
imports no rendering/body-model package at module level."""

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FORBIDDEN = {
    "shared": {"train", "runtime", "bench"},
    "runtime": {"train", "bench"},
    "train": {"runtime", "bench"},
    "bench": {"train"},
}
# Heavy optional packages the deployable runtime must not need at import time.
RUNTIME_TOP_LEVEL_FORBIDDEN = {"pyrender", "trimesh", "anny"}


def imports(path: Path, top_level_only: bool = False):
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if top_level_only else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.split(".")[0], node.lineno
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module.split(".")[0], node.lineno


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_layering(package):
    files = sorted((REPO / package).rglob("*.py"))
    assert files, f"package {package} has no modules"
    bad = [
        f"{f.relative_to(REPO)}:{line} imports {mod}"
        for f in files
        for mod, line in imports(f)
        if mod in FORBIDDEN[package]
    ]
    assert not bad, "\n".join(bad)


def test_runtime_has_no_heavy_top_level_imports():
    bad = [
        f"{f.relative_to(REPO)}:{line} imports {mod}"
        for f in sorted((REPO / "runtime").rglob("*.py"))
        for mod, line in imports(f, top_level_only=True)
        if mod in RUNTIME_TOP_LEVEL_FORBIDDEN
    ]
    assert not bad, "\n".join(bad)


def test_detects_violations(tmp_path):
    # The scanner itself must see both import forms, or the rules above could never fail.
    f = tmp_path / "m.py"
    f.write_text("import train.x\nfrom runtime import y\nfrom . import z\nimport bench.cli\n")
    assert {m for m, _ in imports(f)} == {"train", "runtime", "bench"}

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


def _package(module: str) -> str:
    """The project package a module path names (``depthmocap.runtime.x`` -> ``runtime``), or
    its top-level name for anything else."""
    parts = module.split(".")
    return parts[1] if parts[0] == "depthmocap" and len(parts) > 1 else parts[0]


def imports(path: Path, top_level_only: bool = False, raw: bool = False):
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if top_level_only else ast.walk(tree)
    name = (lambda m: m.split(".")[0]) if raw else _package
    for node in nodes:
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield name(alias.name), node.lineno
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield name(node.module), node.lineno


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


def test_no_bare_package_imports():
    """The packages are installed as depthmocap.*: a bare ``import runtime`` works only inside a
    checkout and fails for every user who installed the wheel."""
    files = [
        p for d in (*FORBIDDEN, "tests", "depthmocap") for p in sorted((REPO / d).rglob("*.py"))
    ]
    bad = [
        f"{f.relative_to(REPO)}:{line} imports {mod}"
        for f in files
        for mod, line in imports(f, raw=True)
        if mod in FORBIDDEN
    ]
    assert not bad, "\n".join(bad)


def test_detects_violations(tmp_path):
    # The scanner itself must see both import forms, or the rules above could never fail.
    f = tmp_path / "m.py"
    f.write_text(
        "import depthmocap.train.x\nfrom depthmocap.runtime import y\nfrom . import z\n"
        "import depthmocap.bench.cli\nimport runtime.tracker\n"
    )
    assert {m for m, _ in imports(f)} == {"train", "runtime", "bench"}
    assert {m for m, _ in imports(f, raw=True)} == {"depthmocap", "runtime"}

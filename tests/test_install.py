"""The checkout installs as one package, ``depthmocap``, usable without the checkout (issue 35).

Builds the project into a fresh virtual environment outside the checkout (``pip install
<checkout>[runtime]``; the dependencies come from the test's own environment through a .pth
file, so nothing is downloaded), then, from another directory: ``import depthmocap`` works,
``import runtime`` fails, and ``runtime-track --input demo`` tracks with the packaged forest and
preset. ``make install-check`` runs exactly this test.
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv with the checkout installed (not editable); returns its bin folder."""
    root = tmp_path_factory.mktemp("install")
    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    # This environment's packages (torch, numpy, pip, setuptools) without its editable
    # install of the project: a plain path in a .pth file does not run the other .pth files.
    Path(purelib, "test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    proc = subprocess.run(
        [
            py,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-build-isolation",
            "--no-index",
            f"{REPO}[runtime]",
        ],
        capture_output=True,
        text=True,
        cwd=root,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return env_dir / "bin"


def _run(args, cwd: Path, **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "DEPTHMOCAP_CACHE"}}
    return subprocess.run(args, capture_output=True, text=True, cwd=cwd, env=env, timeout=300, **kw)


@pytest.mark.slow
def test_one_package_without_the_checkout(installed, tmp_path):
    py = installed / "python"
    code = (
        "import depthmocap, depthmocap.runtime.track_cli as t, depthmocap.shared.resources as r\n"
        "print(r.PACKAGE_ROOT); print(r.is_checkout())\n"
        "print(sorted(p.name for p in r.CONFIGS_DIR.iterdir()))\n"
        "print(sorted(p.name for p in r.MODELS_DIR.iterdir()))\n"
        "import importlib.resources as ir\n"
        "print(ir.files('depthmocap.shared').joinpath('poses.schema.json').is_file())"
    )
    out = _run([py, "-c", code], cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    root, checkout, configs, models, schema = out.stdout.splitlines()
    assert REPO.as_posix() not in root and "site-packages" in root
    assert checkout == "False" and schema == "True"
    assert "hybrid.yaml" in configs and "wei2012.yaml" in configs
    assert "body_template.json" in configs
    assert "forest.npz" in models and "forest_calib.npz" in models
    for name in ("runtime", "shared", "train", "bench"):
        bare = _run([py, "-c", f"import {name}"], cwd=tmp_path)
        assert bare.returncode != 0 and "ModuleNotFoundError" in bare.stderr, name


@pytest.mark.slow
def test_runtime_track_from_another_directory(installed, tmp_path):
    run = _run(
        [installed / "runtime-track", "--input", "demo", "--output", "out", "--stop", "12", "-q"],
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["complete"] and summary["frames"] == 12 and summary["mode"] == "hybrid"
    assert summary["status_counts"]["lost"] == 0
    model = summary["extra"]["model"]
    assert "site-packages" in json.dumps(model) and REPO.as_posix() not in json.dumps(model)
    assert summary["extra"]["preset"] == "shipped" and summary["extra"]["config"] is None
    assert len((tmp_path / "out" / "poses.jsonl").read_text().splitlines()) == 12

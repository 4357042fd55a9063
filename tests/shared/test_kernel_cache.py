"""The compiled kernels' cache folder: named by their sources, so a changed kernel never runs
another's stale compiled copy of it (shared/kernel_cache.py, called by depthmocap/__init__.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from depthmocap.shared import kernel_cache


def _kernels(folder, **sources):
    for name, text in sources.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)


def test_the_folder_changes_with_any_kernel_and_only_with_kernels(tmp_path):
    code = tmp_path / "code"
    _kernels(code, **{"a_kernel.py": "x = 1\n", "sub/b_kernel.py": "y = 2\n", "other.py": "z\n"})
    root = tmp_path / "cache"
    first = kernel_cache.kernel_cache_folder([code], root)
    assert first.parent == root and first.name.startswith("numba-")
    assert kernel_cache.kernel_cache_folder([code], root) == first  # the same sources
    (code / "other.py").write_text("not a kernel\n")
    assert kernel_cache.kernel_cache_folder([code], root) == first
    (code / "sub" / "b_kernel.py").write_text("y = 3\n")  # a kernel deep in a subpackage
    assert kernel_cache.kernel_cache_folder([code], root) != first


def test_using_a_folder_sets_numba_s_cache_and_clears_old_ones(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    root = tmp_path / "cache"
    old, recent = root / "numba-old", root / "numba-recent"
    old.mkdir(parents=True)
    recent.mkdir()
    month_ago = time.time() - 31 * 86400
    os.utime(old, (month_ago, month_ago))
    folder = root / "numba-now"
    assert kernel_cache.use_kernel_cache(folder)
    assert os.environ["NUMBA_CACHE_DIR"] == str(folder) and folder.is_dir()
    assert not old.exists() and recent.exists()


def test_an_unwritable_root_leaves_numba_s_default(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    blocker = tmp_path / "file"
    blocker.write_text("a file where the folder would go")
    assert not kernel_cache.use_kernel_cache(blocker / "numba-x")
    assert "NUMBA_CACHE_DIR" not in os.environ


def _cache_dir_after_import(env: dict) -> str:
    code = "import os, depthmocap; print(os.environ.get('NUMBA_CACHE_DIR'))"
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return run.stdout.strip()


def test_importing_the_package_picks_this_install_s_folder_unless_the_user_chose(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["DEPTHMOCAP_CACHE"] = str(tmp_path / "depthmocap")  # the project's cache root
    chosen = _cache_dir_after_import(env)
    assert os.path.dirname(chosen) == str(tmp_path / "depthmocap")
    assert os.path.basename(chosen).startswith("numba-") and os.path.isdir(chosen)
    assert _cache_dir_after_import(env) == chosen  # the same kernels, the same folder
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    assert _cache_dir_after_import(env) == str(tmp_path / "mine")


def test_a_cache_root_that_cannot_be_made_leaves_numba_s_default(tmp_path):
    """A cache root that cannot be written (a file where its folder would go; a bare
    container's missing home) must not stop the package from importing."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["DEPTHMOCAP_CACHE"] = str(tmp_path / "missing" / "cache")  # a file blocks the path
    (tmp_path / "missing").write_text("not a folder")
    assert _cache_dir_after_import(env) == "None"

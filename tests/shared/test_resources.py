"""depthmocap.shared.resources: shipped data and caches, found in a checkout and when installed."""

from pathlib import Path

from depthmocap.shared import resources


def test_shipped_data_is_beside_the_code():
    assert (resources.CONFIGS_DIR / "hybrid.yaml").is_file()
    assert (resources.MODELS_DIR / "forest.npz").is_file()
    assert resources.is_checkout()  # the tests run from the checkout


def test_cache_root(monkeypatch, tmp_path):
    monkeypatch.setenv("DEPTHMOCAP_CACHE", str(tmp_path / "c"))
    assert resources.cache_root() == tmp_path / "c"
    monkeypatch.delenv("DEPTHMOCAP_CACHE")
    assert resources.cache_root() == resources.PACKAGE_ROOT / ".cache"
    # Installed (no pyproject.toml beside the package): the user's cache, never site-packages.
    monkeypatch.setattr(resources, "PACKAGE_ROOT", tmp_path / "site-packages" / "depthmocap")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert resources.cache_root() == tmp_path / "xdg" / "depthmocap"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert resources.cache_root() == Path.home() / ".cache" / "depthmocap"


def test_model_file_is_absolute_or_under_the_shipped_models(tmp_path):
    assert resources.model_file("forest.npz") == resources.MODELS_DIR / "forest.npz"
    assert resources.model_file("sub/x.json") == resources.MODELS_DIR / "sub" / "x.json"
    assert resources.model_file(tmp_path / "x.json") == tmp_path / "x.json"
    assert resources.model_file(str(tmp_path / "x.json")) == tmp_path / "x.json"

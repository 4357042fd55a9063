import argparse
from dataclasses import dataclass, field
from typing import Literal

import pytest
from depthmocap.shared.config import (
    ConfigError,
    add_cli_args,
    config_from_args,
    config_from_dict,
    field_doc,
    load_config,
    load_settings,
    save_config,
)


@dataclass
class Inner:
    sigma: float = field_doc(0.5, "noise")


@dataclass
class Cfg:
    frames: int = field_doc(10, "how many frames")
    name: str = field_doc("x", "a name")
    mode: Literal["a", "b"] = field_doc("a", "mode")
    flag: bool = field_doc(False, "a switch")
    sizes: list[int] = field_doc([1, 2], "sizes")
    out: str | None = field_doc(None, "optional path")
    inner: Inner = field(default_factory=Inner)


def test_yaml_round_trip(tmp_path):
    cfg = Cfg(frames=3, name="y", mode="b", flag=True, sizes=[4], out="o", inner=Inner(0.1))
    save_config(cfg, tmp_path / "c.yaml")
    assert load_config(Cfg, tmp_path / "c.yaml") == cfg


def test_unknown_key_names_file_and_key(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("frames: 3\nfrmaes: 4\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: unknown key\(s\) frmaes"):
        load_config(Cfg, p)


def test_nested_unknown_and_type_errors():
    with pytest.raises(ConfigError, match=r"config.inner: unknown key\(s\) sigmaa"):
        config_from_dict(Cfg, {"inner": {"sigmaa": 1}})
    with pytest.raises(ConfigError, match="config.frames: expected an integer"):
        config_from_dict(Cfg, {"frames": "ten"})
    with pytest.raises(ConfigError, match="must be one of"):
        config_from_dict(Cfg, {"mode": "c"})
    with pytest.raises(ConfigError, match="expected true/false"):
        config_from_dict(Cfg, {"flag": "yes"})


def test_missing_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(Cfg, tmp_path / "nope.yaml")
    p = tmp_path / "broken.yaml"
    p.write_text("frames: [1,\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(Cfg, p)


def test_a_preset_extends_another_key_by_key(tmp_path):
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "base.yaml").write_text("frames: 3\nname: b\ninner: {sigma: 0.2}\n")
    child = tmp_path / "child.yaml"
    child.write_text("extends: base/base.yaml\nname: c\ninner: {}\n")
    assert load_settings(child) == {"frames": 3, "name": "c", "inner": {"sigma": 0.2}}
    grandchild = tmp_path / "grandchild.yaml"
    grandchild.write_text("extends: child.yaml\nflag: true\ninner: {sigma: 0.3}\n")
    cfg = load_config(Cfg, grandchild)
    assert (cfg.frames, cfg.name, cfg.flag, cfg.inner.sigma) == (3, "c", True, 0.3)
    assert load_settings(tmp_path / "base" / "base.yaml")["name"] == "b"  # base untouched


@pytest.mark.parametrize(
    "text, message",
    [
        ("extends: bad.yaml\n", "extends itself"),
        ("extends: nowhere.yaml\n", "nowhere.yaml"),
        ("extends: [a, b]\n", "must name a YAML file"),
        ("- 1\n- 2\n", "expected a mapping"),
    ],
)
def test_bad_presets_are_reported(tmp_path, text, message):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_settings(bad)


def test_shipped_presets_load():
    from pathlib import Path

    configs = Path(__file__).resolve().parents[2] / "configs"
    shipped = load_settings(configs / "hybrid.yaml")
    assert shipped["keep_better"]["compare_all_tests"] is True
    assert shipped["tracker"] == {"use_labels": True, "use_collision": True}


def test_cli_overrides_only_given_options():
    parser = argparse.ArgumentParser()
    add_cli_args(parser, Cfg)
    args = parser.parse_args(["--frames", "7", "--flag", "--sizes", "3", "4"])
    cfg = config_from_args(Cfg, args, base=Cfg(name="preset"))
    assert cfg.frames == 7 and cfg.flag and cfg.sizes == [3, 4] and cfg.name == "preset"

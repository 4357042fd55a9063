"""Typed configuration: dataclasses filled from YAML presets, and CLIs generated from them.

Every config is a ``@dataclass`` whose fields carry a docstring in ``metadata["help"]`` (use
:func:`field_doc`). :func:`load_config` reads a preset (which may extend another) and rejects
unknown keys and wrong types with a message naming the file and the key. :func:`add_cli_args`
and :func:`config_from_args` turn any config into ``argparse`` options, one per field, so a
CLI is a few lines and never drifts from its config.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

__all__ = [
    "ConfigError",
    "field_doc",
    "config_from_dict",
    "as_config",
    "config_to_dict",
    "load_config",
    "load_settings",
    "merged_settings",
    "save_config",
    "add_cli_args",
    "config_from_args",
]

C = TypeVar("C")


class ConfigError(ValueError):
    """A config file or value that does not fit its dataclass."""


def field_doc(default: Any = dataclasses.MISSING, help: str = "", **kw) -> Any:  # noqa: A002
    """A dataclass field with its documentation; mutable defaults become factories."""
    meta = {"help": help}
    if isinstance(default, (list, dict, tuple)) and not isinstance(default, str):
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta, **kw)
    return dataclasses.field(default=default, metadata=meta, **kw)


def _check_value(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_value(a, value, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(errors[0] if errors else f"{where}: invalid value {value!r}")
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return config_from_dict(tp, value, where)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        item = args[0] if args else Any
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
            return tuple(
                _check_value(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value))
            )
        out = [_check_value(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(out) if origin is tuple else out
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return dict(value)
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: must be one of {list(args)}, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def config_from_dict(cls: type[C], data: dict, where: str = "config") -> C:
    """Build dataclass ``cls`` from a mapping, checking keys and types recursively."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(map(str, unknown))}; known: {', '.join(fields)}"
        )
    kwargs = {k: _check_value(hints[k], v, f"{where}.{k}") for k, v in data.items()}
    return cls(**kwargs)


def as_config(
    cls: type[C],
    config: Any,
    where: str = "config",
    error: type[Exception] = ConfigError,
    over_defaults: bool = False,
) -> C:
    """``config`` as a ``cls``: the defaults for None, itself for an instance, else a mapping
    of its keys (:func:`config_from_dict`). With ``over_defaults`` the mapping changes only
    the keys it names, nested sections included, of ``cls()`` (whose sections' own defaults
    may differ from the class's: a preset that sets one threshold keeps the others). A bad
    mapping raises ``error`` with the message (an ``error`` raised by the config's own checks
    passes through as it is)."""
    if config is None:
        return cls()
    if isinstance(config, cls):
        return config
    try:
        data = dict(config)
        if over_defaults:
            data = _merged(config_to_dict(cls()), data)
        return config_from_dict(cls, data, where)
    except error:
        raise
    except ConfigError as err:
        raise error(str(err)) from None


def config_to_dict(cfg: Any) -> dict:
    """Plain dict (tuples as lists) suitable for YAML/JSON."""

    def plain(v):
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(dataclasses.asdict(cfg))


def load_settings(path: str | Path, _seen: tuple[Path, ...] = ()) -> dict:
    """A YAML preset as a plain mapping (empty file: ``{}``).

    A preset may start from another with ``extends: OTHER.yaml`` (a path relative to the
    preset): its own keys replace the other's, key by key inside nested mappings.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings")
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError(f"{path}: extends must name a YAML file, got {base!r}")
    here = path.resolve()
    if here in _seen:
        raise ConfigError(f"{path}: extends itself (through {' -> '.join(map(str, _seen))})")
    return _merged(load_settings(path.parent / base, (*_seen, here)), data)


def merged_settings(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``, mappings merged key by key (``None`` replaces a mapping:
    it switches a section off)."""
    return _merged(base, over)


def _merged(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``, mappings merged key by key."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            value = _merged(out[key], value)
        out[key] = value
    return out


def load_config(cls: type[C], path: str | Path | None) -> C:
    """Read a YAML preset (:func:`load_settings`) into ``cls``; ``None`` gives the defaults."""
    if path is None:
        return cls()
    return config_from_dict(cls, load_settings(path), where=str(path))


def save_config(cfg: Any, path: str | Path) -> None:
    """Write a config as YAML (saved next to every artifact)."""
    Path(path).write_text(yaml.safe_dump(config_to_dict(cfg), sort_keys=False))


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_cli_args(parser: argparse.ArgumentParser, cls: type) -> None:
    """One option per scalar/list field of ``cls`` (nested dataclasses are skipped: use YAML).

    Defaults are ``None`` (unset) so that only options given on the command line override
    the preset.
    """
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):
            non_none = [a for a in args if a is not type(None)]
            tp = non_none[0] if len(non_none) == 1 else str
            origin, args = typing.get_origin(tp), typing.get_args(tp)
        if dataclasses.is_dataclass(tp):
            continue
        help_ = f.metadata.get("help", "")
        default = f.default if f.default is not dataclasses.MISSING else None
        if default is None and f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            default = f.default_factory()  # type: ignore[misc]
        help_ = f"{help_} (default: {default})"
        if tp is bool:
            parser.add_argument(
                _flag(f.name),
                dest=f.name,
                default=None,
                action=argparse.BooleanOptionalAction,
                help=help_,
            )
        elif origin in (list, tuple):
            item = args[0] if args else str
            parser.add_argument(
                _flag(f.name),
                dest=f.name,
                default=None,
                nargs="+",
                type=item if item in (int, float, str) else str,
                help=help_,
            )
        elif origin is typing.Literal:
            parser.add_argument(
                _flag(f.name), dest=f.name, default=None, choices=list(args), help=help_
            )
        else:
            parser.add_argument(
                _flag(f.name),
                dest=f.name,
                default=None,
                type=tp if tp in (int, float, str) else str,
                help=help_,
            )


def config_from_args(cls: type[C], args: argparse.Namespace, base: C | None = None) -> C:
    """``base`` (or the defaults) with every option given on the command line applied."""
    base = cls() if base is None else base
    data = config_to_dict(base)
    for f in dataclasses.fields(cls):
        value = getattr(args, f.name, None)
        if value is not None:
            data[f.name] = list(value) if isinstance(value, tuple) else value
    return config_from_dict(cls, data, where="command line")

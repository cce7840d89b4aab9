"""Load the TOML files under ``configs/`` into typed, frozen dataclasses.

Every default of SEESys (thresholds, windows, ports, camera) lives in ``configs/<section>.toml``. A part defines
a dataclass for its section and calls :func:`load_section`; the loader checks that the file has exactly the
dataclass's keys, with values of the declared types, and raises :class:`ConfigError` naming the file and key
otherwise. Nested dataclasses map to TOML tables.

The folder is ``$SEESYS_CONFIG_DIR`` when set, else ``configs/`` of the SEESys home (:mod:`seesys.io.resources`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from seesys.core.errors import ConfigError
from seesys.io import resources

T = TypeVar("T")

CONFIG_DIR_ENV = "SEESYS_CONFIG_DIR"


def config_dir() -> Path:
    """The folder the TOML files are read from."""
    env = os.environ.get(CONFIG_DIR_ENV)
    if env:
        return Path(env)
    return resources.home() / "configs"


def read_toml(path: Path) -> dict[str, Any]:
    """Parse one TOML file, turning a missing file or a syntax error into a :class:`ConfigError`."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"configuration file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None


def _check_value(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
        return build(annotation, value, where)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is type(None):
                continue
            try:
                return _check_value(value, option, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: {value!r} is not one of {annotation}")
    if origin in (list, tuple):
        args = typing.get_args(annotation)
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        item_type = args[0] if args else Any
        items = [_check_value(v, item_type, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
        return dict(value)
    if annotation is Any:
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation in (str, bool):
        if not isinstance(value, annotation):
            raise ConfigError(f"{where}: expected {annotation.__name__}, got {value!r}")
        return value
    if isinstance(annotation, type) and issubclass(annotation, str):  # str-valued enums
        try:
            return annotation(value)
        except ValueError:
            raise ConfigError(f"{where}: {value!r} is not a valid {annotation.__name__}") from None
    return value


def build(cls: type[T], data: dict[str, Any], where: str) -> T:
    """Build dataclass ``cls`` from ``data``, which must have exactly its fields (no unknown, none missing)."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (expected {', '.join(fields)})")
    missing = sorted(set(fields) - set(data))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {', '.join(missing)}")
    values = {name: _check_value(data[name], hints[name], f"{where}.{name}") for name in fields}
    try:
        return cls(**values)
    except ValueError as e:  # a dataclass's own check of its values (__post_init__)
        raise ConfigError(f"{where}: {e}") from None


def load_section(name: str, cls: type[T], directory: Path | None = None) -> T:
    """Load ``configs/<name>.toml`` into ``cls``; ``directory`` overrides the config folder."""
    path = (directory or config_dir()) / f"{name}.toml"
    return build(cls, read_toml(path), str(path))


def replace_fields(obj: T, **changes: Any) -> T:
    """A copy of the frozen config ``obj`` with some fields changed (for command-line overrides)."""
    return dataclasses.replace(obj, **changes)


def as_dict(obj: Any) -> dict[str, Any]:
    """The config as plain data, for ``session.json``."""
    return dataclasses.asdict(obj)


def write_config_dir(destination: Path, overrides: dict[str, object]) -> Path:
    """Copy ``configs/*.toml`` into ``destination`` with each ``key = value`` of ``overrides`` replaced.

    A key is found by name, or as ``file.key`` (``slam.stall_timeout_s`` for ``slam.toml``) where the name is used
    in more than one file; within a file the first ``key =`` line is replaced. An unknown key, or an unqualified
    one that more than one file uses, is an error: a renamed key, or one added to another file, cannot silently
    leave a caller on the defaults or change the wrong setting.
    """
    sources = sorted(config_dir().glob("*.toml"))
    texts = {source.stem: source.read_text() for source in sources}
    for name, value in overrides.items():
        stem, _, key = name.rpartition(".")
        line = re.compile(rf"^{re.escape(key)} = .*$", re.MULTILINE)
        where = [s for s in ([stem] if stem else texts) if s in texts and line.search(texts[s])]
        if not where:
            raise KeyError(f"no such configuration key: {name}")
        if len(where) > 1:
            raise KeyError(f"configuration key {key} is in {', '.join(f'{s}.toml' for s in where)}: "
                           f"name it as {where[0]}.{key} (file.key)")
        texts[where[0]] = line.sub(lambda _: f"{key} = {json.dumps(value)}", texts[where[0]], count=1)
    destination.mkdir(parents=True, exist_ok=True)
    for source in sources:
        (destination / source.name).write_text(texts[source.stem])
    return destination

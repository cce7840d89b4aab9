"""Load the TOML files under ``configs/`` into typed, frozen dataclasses.

Every default of SEESys (thresholds, windows, ports, camera) lives in ``configs/<section>.toml``. A part defines
a dataclass for its section and calls :func:`load_section`; the loader checks that the file has exactly the
dataclass's keys, with values of the declared types, and raises :class:`ConfigError` naming the file and key
otherwise. Nested dataclasses map to TOML tables.

The folder is ``$SEESYS_CONFIG_DIR`` when set, else ``configs/`` of the SEESys home (:mod:`seesys.io.resources`).
A folder is read once per process (:class:`ConfigSet`, again only when one of its files changes). Settings reach a
child process one way: the parent changes a section with ``dataclasses.replace`` (:meth:`ConfigSet.replaced`),
writes the whole set into a folder of the session (:meth:`ConfigSet.write`) and points ``$SEESYS_CONFIG_DIR`` at it.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import os
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import tomli_w

from seesys.core.errors import ConfigError
from seesys.io import resources

if TYPE_CHECKING:  # the stubs' name for "an instance of any dataclass"; no such module at run time
    from _typeshed import DataclassInstance

# Every settings section is a dataclass: build() reads its fields, replace_fields() copies it.
T = TypeVar("T", bound="DataclassInstance")

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
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):  # a dataclass, not an instance
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


def to_toml_data(value: Any) -> Any:
    """A settings value as TOML data: a dataclass as a table of its fields, enums by value, tuples as lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_toml_data(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, (list, tuple)):
        return [to_toml_data(v) for v in value]
    if isinstance(value, Mapping):
        return {k: to_toml_data(v) for k, v in value.items()}
    if isinstance(value, Path):
        return str(value)
    return value


def _keys_of(data: dict[str, Any], own: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with only the keys ``own`` has, table by table."""
    return {
        key: _keys_of(v, own[key]) if isinstance(v, dict) and isinstance(own[key], Mapping) else v
        for key, v in data.items()
        if key in own
    }


def _find_key(table: Any, key: str) -> list[str | int] | None:
    """The path of the first ``key`` in ``table``, its sub-tables and arrays of tables, in the file's order (None:
    not there)."""
    items = table.items() if isinstance(table, Mapping) else enumerate(table) if isinstance(table, list) else ()
    for name, value in items:
        if name == key:
            return [name]
        below = _find_key(value, key)
        if below is not None:
            return [name, *below]
    return None


def _set(table: Any, path: list[str | int], value: Any) -> Any:
    """A copy of ``table`` with the value at ``path`` replaced (the tables and arrays on the way copied)."""
    head, *rest = path
    changed = _set(table[head], rest, value) if rest else value
    if isinstance(table, list):
        return [changed if i == head else item for i, item in enumerate(table)]
    return {**table, head: changed}


@dataclass(frozen=True)
class ConfigSet:
    """Every ``*.toml`` of a configuration folder, parsed: ``sections`` by file name without ``.toml`` (shared by
    every reader of the folder: never changed in place).

    Read once (:meth:`read`), built into a part's typed settings (:meth:`section`), changed for a child process
    with a typed value (:meth:`replaced`) and written out whole (:meth:`write`): no text of a file is edited."""

    folder: Path
    sections: Mapping[str, Mapping[str, Any]]

    @classmethod
    def read(cls, directory: Path | None = None) -> ConfigSet:
        """The files of ``directory`` (default: :func:`config_dir`); a file it lacks is a ConfigError when asked
        for (:meth:`data`)."""
        folder = Path(directory) if directory is not None else config_dir()
        stats = [(p.name, p.stat()) for p in sorted(folder.glob("*.toml"))]
        stamp = tuple((name, st.st_mtime_ns, st.st_size) for name, st in stats)
        return _read_folder(folder.resolve(), stamp)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.toml"

    def data(self, name: str) -> Mapping[str, Any]:
        """The parsed file ``name``; ConfigError when the folder has no such file."""
        if name not in self.sections:
            raise ConfigError(f"configuration file not found: {self.path(name)}")
        return self.sections[name]

    def section(self, name: str, cls: type[T]) -> T:
        """File ``name`` built into ``cls`` (exactly its keys, of its types; ConfigError naming file and key)."""
        return build(cls, dict(self.data(name)), str(self.path(name)))

    def replaced(self, name: str, value: Any) -> ConfigSet:
        """This set with file ``name`` holding the settings ``value`` (a dataclass built from it, changed with
        ``dataclasses.replace``). A value that carries another file's settings too (the monitor's shared windows, its
        second opinion's span from labels.toml) writes only the keys this file has, table by table."""
        return dataclasses.replace(
            self, sections={**self.sections, name: _keys_of(to_toml_data(value), self.data(name))}
        )

    def with_values(self, values: Mapping[str, object]) -> ConfigSet:
        """This set with settings changed by key: ``key`` where one file has it, else ``file.key`` (the first
        ``key`` of that file, at any depth, arrays of tables included). For tests and scripted experiments; code
        that starts a child changes a typed section with :meth:`replaced` instead. KeyError naming an unknown or
        ambiguous key."""
        sections = dict(self.sections)
        for name, value in values.items():
            stem, _, key = name.rpartition(".")
            where = {
                s: path
                for s in ([stem] if stem else sections)
                if s in sections and (path := _find_key(sections[s], key)) is not None
            }
            if not where:
                raise KeyError(f"no such configuration key: {name}")
            if len(where) > 1:
                raise KeyError(
                    f"configuration key {key} is in {', '.join(f'{s}.toml' for s in where)}: "
                    f"name it as {next(iter(where))}.{key} (file.key)"
                )
            ((file, path),) = where.items()
            sections[file] = _set(sections[file], path, value)
        return dataclasses.replace(self, sections=sections)

    def write(self, destination: Path) -> Path:
        """Every file of the set into ``destination`` (created), for ``$SEESYS_CONFIG_DIR`` of a child."""
        destination.mkdir(parents=True, exist_ok=True)
        for name, data in self.sections.items():
            with open(destination / f"{name}.toml", "wb") as f:
                tomli_w.dump(data, f)
        return destination


@functools.lru_cache(maxsize=32)
def _read_folder(folder: Path, stamp: tuple[tuple[str, int, int], ...]) -> ConfigSet:
    """The files of ``folder`` as they were at ``stamp`` (names, modification times and sizes): a folder whose
    files have not changed is parsed once per process."""
    return ConfigSet(folder, {Path(name).stem: read_toml(folder / name) for name, _, _ in stamp})


def load_section(name: str, cls: type[T], directory: Path | None = None) -> T:
    """Load ``configs/<name>.toml`` into ``cls``; ``directory`` overrides the config folder."""
    return ConfigSet.read(directory).section(name, cls)


def replace_fields(obj: T, **changes: Any) -> T:
    """A copy of the frozen config ``obj`` with some fields changed (for command-line overrides)."""
    return dataclasses.replace(obj, **changes)


def as_dict(obj: Any) -> dict[str, Any]:
    """The config as plain data, for ``session.json``."""
    return dataclasses.asdict(obj)


def write_config_dir(destination: Path, values: Mapping[str, object]) -> Path:
    """The configuration in use with ``values`` changed by key (:meth:`ConfigSet.with_values`), written into
    ``destination``: a folder for ``$SEESYS_CONFIG_DIR`` in tests and scripted experiments."""
    return ConfigSet.read().with_values(values).write(destination)

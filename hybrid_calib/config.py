"""Configs: frozen dataclasses with defaults, merged with user overrides, then frozen.

Every configurable class has a ``@dataclass(frozen=True)`` config with a one-line comment per
field. ``merge(Conf, overrides)`` builds one from a nested mapping and rejects unknown keys, so a
typo fails at start instead of being ignored. ``to_dict`` gives the JSON saved beside outputs.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

C = TypeVar("C")


class ConfigError(ValueError):
    """An unknown or ill-typed configuration key."""


def merge(cls: type[C], overrides: Mapping[str, Any] | C | None = None, _path: str = "") -> C:
    """Build ``cls`` (a frozen dataclass) from its defaults updated by ``overrides``.

    Nested dataclass fields accept nested mappings. Unknown keys raise ``ConfigError`` naming the
    key and the valid ones.
    """
    if overrides is None:
        return cls()
    if isinstance(overrides, cls):
        return overrides
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"config {_path or cls.__name__}: expected a mapping, got {type(overrides)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ConfigError(
            f"unknown option(s) {unknown} for {cls.__name__}{' at ' + _path if _path else ''}; "
            f"valid options: {sorted(fields)}"
        )
    kwargs = {}
    for key, value in overrides.items():
        hint = hints.get(key)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            kwargs[key] = merge(hint, value, f"{_path}{key}.")
        elif isinstance(value, list):
            kwargs[key] = tuple(value)
        else:
            kwargs[key] = value
    return dataclasses.replace(cls(), **kwargs)


def to_dict(conf: Any) -> dict[str, Any]:
    """Dataclass config -> plain nested dict (tuples become lists), for JSON."""
    return json.loads(json.dumps(dataclasses.asdict(conf), default=list))


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """Command-line ``key=value`` / ``a.b=value`` overrides -> nested dict (values parsed as JSON
    when possible, else kept as strings)."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"override {item!r} must look like key=value")
        key, raw = item.split("=", 1)
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        node = out
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return out


def save_json_atomic(path: Path, obj: Any) -> Path:
    """Write JSON to ``path`` atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, default=_json_default))
    tmp.replace(path)
    return path


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    if dataclasses.is_dataclass(o):
        return dataclasses.asdict(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")

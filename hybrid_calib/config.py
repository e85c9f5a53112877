"""Configs: frozen dataclasses with defaults, merged with user overrides, then frozen.

Every configurable class has a ``@dataclass(frozen=True)`` config with a one-line comment per
field. ``merge(Conf, overrides)`` builds one from a nested mapping and rejects unknown keys and
values of the wrong type (checked against the field annotations: ``"off"`` is not a bool, ``"abc"``
not an int), so a typo fails at start instead of being ignored or crashing later. ``to_dict`` gives
the JSON saved beside outputs.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
import os
import re
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from hybrid_calib.errors import HybridCalibError

C = TypeVar("C")


class ConfigError(HybridCalibError, ValueError):
    """An unknown or ill-typed configuration key (the message names the option and its valid values)."""


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """The resolved annotations of a config class ({} when a name in them resolves only for a type checker)."""
    try:
        return typing.get_type_hints(cls)
    except (NameError, TypeError):
        return {}


def check_fields(conf: Any) -> None:
    """``ValueError`` naming the first field of the dataclass ``conf`` whose value does not fit its annotation
    (``check_type``), as ``merge`` names an option; a list where a tuple is annotated becomes the tuple (a frozen
    config holds hashable values). ``merge`` checks what a user types; this is the same check for a config built
    directly, as the examples and the API do (probe 51: ``SimConfig(frames=2.5)`` was accepted and failed deep inside
    ``simulate`` with a bare TypeError). Called by ``require`` and ``require_ranges``, so every ``__post_init__``
    that checks a rule checks the types first; once per instance (a ``__post_init__`` calling both, or calling this
    before them, does not check twice: the instance keeps a mark outside its fields)."""
    if conf.__dict__.get("_fields_checked"):
        return
    for f in dataclasses.fields(conf):
        value, hint = getattr(conf, f.name), _hints(type(conf)).get(f.name)
        if hint is None or check_type(value, hint):
            if isinstance(value, list) and (hint is tuple or typing.get_origin(hint) is tuple):
                object.__setattr__(conf, f.name, tuple(value))
            continue
        raise ValueError(f"option {f.name}={value!r} ({type(value).__name__}) is not a valid {_type_name(hint)} for "
                         f"{type(conf).__name__}.{f.name}")
    object.__setattr__(conf, "_fields_checked", True)


class FrozenDict(dict):
    """A dict that refuses changes: the dict-valued options of a frozen config (``HybridConfig.data``,
    ``SimConfig.world``, ...), which a frozen dataclass alone leaves open to ``conf.data["x"] = ...`` (a run's
    recorded config would then not be the one it ran with). Reads, ``{**d}``, JSON and pickling (worker processes,
    Ray) are a dict's."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a config's options are frozen: build another config (merge or dataclasses.replace) instead "
                        "of changing this one")

    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):
        return FrozenDict, (dict(self),)

    def __deepcopy__(self, memo):
        import copy

        return FrozenDict({k: copy.deepcopy(v, memo) for k, v in self.items()})


def frozen(value: Any) -> Any:
    """``value`` with every mapping in it (nested, in lists and tuples too) a ``FrozenDict``."""
    if isinstance(value, Mapping):
        return FrozenDict({k: frozen(v) for k, v in value.items()})
    if isinstance(value, list):
        return [frozen(v) for v in value]
    if isinstance(value, tuple):
        return tuple(frozen(v) for v in value)
    return value


def freeze_dict_fields(conf: Any) -> None:
    """Make every dict-valued field of the frozen dataclass ``conf`` a ``FrozenDict`` (its ``__post_init__`` calls
    this first)."""
    for f in dataclasses.fields(conf):
        value = getattr(conf, f.name)
        if isinstance(value, Mapping) and type(value) is not FrozenDict:
            object.__setattr__(conf, f.name, frozen(value))


def require(conf: Any, rules: Mapping[str, bool]) -> None:
    """Raise ``ValueError`` naming each rule of ``rules`` (its text, e.g. ``"0 < pair_dt_s < max_gap_s"``) that is
    False, with the values of the fields it names: "LeverArmConfig: need sweep_noise_scale > 0 (got
    sweep_noise_scale=0)". For ``__post_init__`` checks, so the message names the option the user set; the fields'
    types are checked first (``check_fields``)."""
    check_fields(conf)
    failing = [text for text, ok in rules.items() if not ok]
    if not failing:
        return
    names = [f.name for f in dataclasses.fields(conf)]
    used = [n for n in names if any(re.search(rf"\b{n}\b", t) for t in failing)]
    if not used:  # a rule on every field ("finite numbers"): the fields that break it, else all ("got )" said nothing)
        used = [n for n in names if isinstance(v := getattr(conf, n), float) and not math.isfinite(v)] or names
    got = ", ".join(f"{n}={getattr(conf, n)!r}" for n in used)
    raise ValueError(f"{type(conf).__name__}: need {'; '.join(failing)} (got {got})")


MAX_SEED = 2**63  # a seed is 0..MAX_SEED-1: numpy's generators take no negative one; --seed's bound (probe 100)


def check_seed(conf: Any) -> None:
    """``ValueError`` unless ``conf.seed`` is in 0..2**63-1, naming ``conf``'s class and --seed (one rule for every
    config with a seed: --set seed=1e26 had been accepted, probe 100)."""
    if not 0 <= conf.seed < MAX_SEED:
        raise ValueError(f"{type(conf).__name__}.seed must be in 0..2**63-1 (--seed), got {conf.seed}")


def is_number(x) -> bool:
    """A finite JSON number (int or float; not bool): a record's field, a result's read back, an option's value."""
    try:  # an integer beyond a float's range (JSON allows 400 digits) is not a number here either (probe 63)
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
    except OverflowError:
        return False


def json_numbers(x) -> bool:
    """Whether ``x`` holds numbers only, as JSON writes them: an int or float (not bool), a numpy number or
    numeric array, or a (nested) list / tuple of such. Text that reads as a number ("1", "1e3") is not one:
    numpy's ``asarray(..., float64)`` converts it silently (probes 109 and 110: a checkpoint's scales and its
    out-of-domain threshold written as text were taken)."""
    if isinstance(x, bool):
        return False
    if isinstance(x, (int, float, np.number)):
        return True
    if isinstance(x, np.ndarray):
        return x.dtype.kind in "iuf"
    return isinstance(x, (list, tuple)) and all(json_numbers(v) for v in x)


def finite(*values: Any) -> bool:
    """Whether every value ``is_number``: numpy's ``isfinite`` on an int beyond 2**64 was an error that named no
    option (probe 79)."""
    return all(is_number(v) for v in values)


_INTERVAL = re.compile(r"^([\[(])\s*([^,\s]+)\s*,\s*([^\])\s]+)\s*([\])])$")


def require_ranges(conf: Any, ranges: Mapping[str, str]) -> None:
    """Raise ``ValueError`` naming every field of ``conf`` outside its interval, written as in maths:
    ``{"kernel_scale": "(0, 100]", "min_rows": "[0, 1e6]"}`` ("(" / ")" open, "[" / "]" closed; a tuple
    field: each element). For ``__post_init__`` checks (``require``'s message: "RadarPixelFactorConfig:
    need kernel_scale in (0, 100] (got kernel_scale=1e+300)"). NaN is outside every interval. The bounds are
    what the code can compute with and what is physically sensible, not tuning ranges."""
    rules = {}
    for name, spec in ranges.items():
        m = _INTERVAL.match(spec)
        if m is None:
            raise TypeError(f"require_ranges: {spec!r} is not an interval like '(0, 1]'")
        lo, hi = float(m[2]), float(m[3])
        value = getattr(conf, name)
        values = value if isinstance(value, (tuple, list)) else (value,)
        rules[f"{name} in {spec}"] = all(
            isinstance(v, numbers.Real) and not isinstance(v, bool)
            and (lo < v if m[1] == "(" else lo <= v) and (v < hi if m[4] == ")" else v <= hi) for v in values)
    require(conf, rules)


def merge(cls: type[C], overrides: Mapping[str, Any] | C | None = None, _path: str = "") -> C:
    """Build ``cls`` (a frozen dataclass) from its defaults updated by ``overrides``.

    Nested dataclass fields accept nested mappings. Unknown keys raise ``ConfigError`` naming the
    key and the valid ones; a value whose type does not match the field's annotation raises
    ``ConfigError`` naming the option, the value and the expected type (``check_type``).
    """
    if overrides is None:
        return cls()
    if isinstance(overrides, cls):
        return overrides
    if not isinstance(overrides, Mapping):
        where = _path.rstrip(".") or cls.__name__
        raise ConfigError(f"option {where}={overrides!r} sets a group of options ({cls.__name__}), not a value; "
                          f"set its keys instead, e.g. --set {where}.KEY=VALUE (keys: "
                          f"{sorted(f.name for f in dataclasses.fields(cls))})")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        # a group's prefix where the options are the group's own (probe 42: inspect --set data.radar_filter...,
        # calibrate's spelling, where inspect's options are DataConfig's)
        extra = unknown[0] if len(unknown) == 1 else ""
        drop = (f"; drop the '{extra}.' prefix: the options here are {cls.__name__}'s own"
                if extra and isinstance(overrides[extra], Mapping) and overrides[extra]
                and set(overrides[extra]) <= set(fields) else "")
        raise ConfigError(
            f"unknown option(s) {unknown} for {cls.__name__}{' at ' + _path.rstrip('.') if _path else ''}; "
            f"valid options: {sorted(fields)}{drop}"
        )
    kwargs = {}
    for key, value in overrides.items():
        hint = hints.get(key)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            kwargs[key] = merge(hint, value, f"{_path}{key}.")
            continue
        if hint is str and isinstance(value, os.PathLike):  # a Path for a path option (the API's natural type)
            value = os.fspath(value)
        if hint is not None and not check_type(value, hint):
            listy = isinstance(value, str) and any(t in _type_name(hint) for t in ("tuple", "list"))
            raise ConfigError(f"option {_path}{key}={value!r} ({type(value).__name__}) is not a valid "
                              f"{_type_name(hint)} for {cls.__name__}.{key}; e.g. --set {_path}{key}="
                              f"{json.dumps(getattr(cls(), key), default=str)} (the default)"
                              + ((f"; a list is JSON with quoted strings: --set '{_path}{key}=[\"a\", \"b\"]'"
                                  if "str" in _type_name(hint) else f"; a list is JSON: --set '{_path}{key}="
                                  f"{_number_list_example(_type_name(hint))}'")
                                 if listy else ""))
        kwargs[key] = tuple(value) if isinstance(value, list) else value
    try:
        return dataclasses.replace(cls(), **kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as e:  # the dataclass's own checks (__post_init__)
        raise ConfigError(f"invalid {cls.__name__}{' at ' + _path.rstrip('.') if _path else ''}: {e}") from None


def _number_list_example(type_name: str) -> str:
    """A JSON list of numbers for a tuple of numbers (``[0, 0, 1]``): as many as a fixed-length tuple holds (two for
    ``...``)."""
    n = type_name.count("float") + type_name.count("int")
    return "[" + ", ".join(["0"] * ((n if n and "..." not in type_name else 2) - 1) + ["1"]) + "]"


def check_type(value: Any, hint: Any) -> bool:
    """Whether ``value`` (parsed JSON or Python) fits the annotation ``hint``.

    Strict where a command-line typo would otherwise slip through: a bool field takes only
    ``true``/``false`` (not ``"off"`` or ``1``), an int field only integers, a float field ints or
    floats, a str field only strings; tuples/lists are checked element-wise. Annotations it does not
    know (``Any``, arrays, classes) accept anything.
    """
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(check_type(value, a) for a in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, (bool, np.bool_))
    if hint is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if hint is float:
        return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if hint is str:
        return isinstance(value, str)
    if hint in (tuple, list) or origin in (tuple, list):
        if not isinstance(value, (tuple, list)):
            return False
        if not args:
            return True
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            return len(value) == len(args) and all(check_type(v, a) for v, a in zip(value, args))
        return all(check_type(v, args[0]) for v in value)
    if hint is dict or origin is dict:
        return isinstance(value, Mapping)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return isinstance(value, (hint, Mapping))
    return True


def _type_name(hint: Any) -> str:
    if isinstance(hint, type) and typing.get_origin(hint) is None:
        return {"bool": "bool (true/false)", "int": "integer", "float": "number", "str": "string"}.get(
            hint.__name__, hint.__name__)
    return str(hint).replace("typing.", "")


def to_dict(conf: Any) -> dict[str, Any]:
    """Dataclass config -> plain nested dict (tuples become lists), for JSON."""
    return json.loads(json.dumps(dataclasses.asdict(conf), default=list))


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """Command-line ``key=value`` / ``a.b=value`` overrides -> nested dict (values parsed as JSON
    when possible, else kept as strings)."""
    out: dict[str, Any] = {}
    given: dict[str, str] = {}  # dotted key -> the item that set it
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: an override must look like KEY=VALUE (nested: a.b=VALUE; "
                              "VALUE is JSON when it parses, e.g. true, 3, [1, 2], else a string)")
        key, raw = item.split("=", 1)
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        except (ValueError, RecursionError) as e:  # thousands of digits, or of nested brackets (probe 27)
            shown = item if len(item) <= 60 else item[:40] + f"...({len(item)} characters)"
            why = "is nested too deeply" if isinstance(e, RecursionError) else f"does not read as a number ({e})"
            raise ConfigError(f"--set {shown!r}: its value {why}; give a value inside the option's interval") from None
        # the same option twice (last one won, silently), or an option and a key inside it (an internal error)
        clash = next((k for k in given if k == key or k.startswith(key + ".") or key.startswith(k + ".")), None)
        if clash is not None and not (clash == key and given[clash] == item):
            raise ConfigError(f"--set {given[clash]!r} and {item!r} set the same option; give it once")
        given[key] = item
        node = out
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return out


def deep_update(base: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated in place by ``overrides`` key by key, nested dicts merged rather than replaced
    (``--set export.sigma_scale=1.2`` changes that one value of a checkpoint's export block and keeps
    the others). Returns ``base``."""
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(base.get(key), dict):
            deep_update(base[key], value)
        else:
            base[key] = value
    return base


def changed_options(old: Mapping[str, Any], new: Mapping[str, Any], skip: Iterable[str] = (),
                    whole: Iterable[str] = ()) -> list[str]:
    """What differs between two records of a run's options (nested dicts, e.g. ``to_dict`` of a config), in words:
    ``"a.b: 1 -> 2"`` (JSON values, long ones cut). ``skip``: dotted keys not compared; ``whole``: keys compared as
    one value, not descended into. A key the old record lacks (written by an earlier version) is not held against
    it."""
    skip, whole = set(skip), set(whole)

    def flat(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in d.items():
            key = f"{prefix}{k}"
            if isinstance(v, Mapping) and v and key not in whole:
                out.update(flat(v, f"{key}."))
            else:
                out[key] = v
        return out

    def short(v: Any) -> str:
        text = json.dumps(v, default=str)
        return text if len(text) <= 60 else text[:57] + "..."

    a, b = flat(json.loads(json.dumps(old, default=str))), flat(json.loads(json.dumps(new, default=str)))
    return [f"{k}: {short(a[k])} -> {short(v)}" for k, v in b.items() if k in a and k not in skip and a[k] != v]


def read_out_record(path: Path, what: str, records: str) -> dict[str, Any] | None:
    """The JSON object an earlier run left in its --out to say what it was computed with (``path``), or None
    when there is none. ``DataError`` naming the file when it does not read back as an object: "the
    ``what`` of this --out is unreadable (...); it records ``records``" (``records`` also says what to do)."""
    from hybrid_calib.errors import DataError

    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict):
            raise TypeError(f"a JSON {type(doc).__name__}, not an object")
    except (OSError, ValueError, TypeError, RecursionError) as e:
        raise DataError(f"the {what} of this --out is unreadable ({type(e).__name__}: {str(e)[:200]}); it records "
                        f"{records}",
                        path=str(path)) from None
    return doc


def save_text_atomic(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (``hybrid_calib.atomic``); the parent is created."""
    from hybrid_calib.atomic import write_bytes_atomic

    return write_bytes_atomic(path, text.encode("utf-8"))


def save_json_atomic(path: Path, obj: Any) -> Path:
    """Write JSON to ``path`` atomically (temp file + rename)."""
    return save_text_atomic(path, json.dumps(obj, indent=2, default=json_default))


def json_default(o: Any) -> Any:
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

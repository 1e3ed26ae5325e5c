"""Config dataclasses from Hydra/OmegaConf mappings, with one error for unknown keys.

`coerce_config` builds a dataclass from an instance, a mapping or ``None``; `check_known_keys` is the same unknown-key
error for callers that split one mapping over several dataclasses; `check_whole`, `check_number` and
`check_instance` are the type checks of config fields and arguments, with errors that name them. The module depends
on no other part of ``tvrecon``.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

import numpy as np

__all__ = [
    "NOT_IN_KEY",
    "OMIT_IF_DEFAULT",
    "check_instance",
    "check_fixed_tuple",
    "check_known_keys",
    "check_number",
    "check_whole",
    "coerce_config",
    "field_names",
    "omitted_from_key",
]

C = TypeVar("C")

#: ``dataclasses.field(metadata=OMIT_IF_DEFAULT)``: a config field added after data was cached. While it holds its
#: default it stays out of the data cache key (``tvrecon.data.cache.store``), so the keys of existing samples do not
#: change; any other value enters the key like every field.
OMIT_IF_DEFAULT = {"cache_key": "omit_if_default"}

#: ``dataclasses.field(metadata=NOT_IN_KEY)``: a config field that never enters the data cache key, whatever its
#: value: how a result is computed, not what it is (e.g. ``PressConfig.compile``, equal readings to float32 round-off).
NOT_IN_KEY = {"cache_key": "never"}


def omitted_from_key(f: dataclasses.Field, value: Any) -> bool:
    """Whether field ``f`` holding ``value`` stays out of a cache key: it is marked ``NOT_IN_KEY``, or it is marked
    ``OMIT_IF_DEFAULT`` and equals its default (a plain ``default``; fields with a ``default_factory`` are never
    omitted)."""
    if f.metadata.get("cache_key") == "never":
        return True
    if f.metadata.get("cache_key") != "omit_if_default" or f.default is dataclasses.MISSING:
        return False
    return type(value) is type(f.default) and value == f.default


def field_names(cls: type) -> tuple[str, ...]:
    """Names of the fields of dataclass ``cls``, in declaration order."""
    return tuple(f.name for f in dataclasses.fields(cls))


def check_known_keys(keys: Iterable[str], valid: Iterable[str], what: str) -> None:
    """Raise ValueError naming the keys not in ``valid`` and listing the valid ones.

    Args:
        keys: the given option names.
        valid: the accepted option names.
        what: what the options configure, as the error names it (e.g. ``"press"``, ``"SensorConfig"``).
    """
    valid = set(valid)
    unknown = sorted(set(keys) - valid)
    if unknown:
        raise ValueError(f"unknown {what} option(s) {unknown}; valid: {sorted(valid)}")


def coerce_config(cls: type[C], value: C | Mapping[str, Any] | None, what: str | None = None) -> C:
    """Build dataclass ``cls`` from an instance, a mapping (e.g. a Hydra ``DictConfig``) or ``None`` (defaults).

    Lists become tuples; an int given for a ``float`` field becomes a float (``sensor.E=3`` and ``sensor.E=3.0`` are
    one config and one cache key); a mapping given for a field whose type is a dataclass builds that dataclass the
    same way (its errors name the field).

    Args:
        cls: the dataclass type.
        value: an instance of ``cls`` (returned as is), a mapping of field values, or None.
        what: how errors name the config (default: the class name).

    Returns:
        An instance of ``cls``. Raises ValueError naming unknown keys and listing the valid ones.
    """
    what = what or cls.__name__
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        try:
            from omegaconf import DictConfig, OmegaConf

            if isinstance(value, DictConfig):
                value = OmegaConf.to_container(value, resolve=True)
        except ImportError:  # pragma: no cover
            pass
    if not isinstance(value, Mapping):
        raise ValueError(f"{what} config must be a {cls.__name__} or a mapping, got {type(value).__name__}")
    check_known_keys(value, field_names(cls), what)
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}
    hints = typing.get_type_hints(cls)
    for k, v in kwargs.items():
        hint = hints.get(k)
        check_fixed_tuple(v, hint, k, what)
        if hint is float and isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_):
            kwargs[k] = float(v)
        elif isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(v, Mapping):
            kwargs[k] = coerce_config(hint, v, k)
    return cls(**kwargs)


def check_fixed_tuple(value: Any, hint: Any, name: str, what: str) -> None:
    """Refuse a value of a fixed-length tuple field (``place_xy: tuple[float, float]``) with another length, or with a
    non-number where numbers are expected; a variable-length tuple, another type or None (where allowed) passes.

    Before, ``place_xy=[0.5]`` ran a whole robot episode and ended in ``IndexError: tuple index out of range``.

    Raises:
        ValueError / TypeError: naming the field ``name`` (of the config ``what``) and the value given.
    """
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if value is None:
            return
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) != 1:
            return
        hint = args[0]
    parts = typing.get_args(hint)
    if typing.get_origin(hint) is not tuple or not parts or Ellipsis in parts or not isinstance(value, tuple):
        return
    if len(value) != len(parts):
        raise ValueError(f"{name} must hold {len(parts)} values ({what} config), got {len(value)}: {list(value)}")
    for part, item in zip(parts, value, strict=True):
        if part in (int, float):
            check_number(item, f"{name} ({what} config) {list(value)}: each value")


def check_whole(value: Any, name: str, minimum: int | None = None) -> int:
    """``value`` as an int when it is a whole number (``40``, ``40.0``, a numpy integer), else an error naming ``name``.

    Counts, worker numbers and grid sizes go through here so that ``n_grid=40.7`` or ``num_samples=2.5`` are refused
    instead of silently truncated, and ``"40"`` or ``True`` are refused instead of taken as numbers.

    Raises:
        TypeError: ``value`` is not a number (a string, a bool, None, a sequence).
        ValueError: ``value`` is a number but not whole, or below ``minimum``.
    """
    if isinstance(value, bool | np.bool_ | str | bytes) or value is None:
        raise TypeError(f"{name} must be a whole number, got {value!r} ({type(value).__name__})")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a whole number, got {value!r} ({type(value).__name__})") from None
    if not number.is_integer():
        raise ValueError(f"{name} must be a whole number, got {value!r}")
    if minimum is not None and number < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    return int(number)


def check_number(value: Any, name: str) -> None:
    """Raise TypeError naming ``name`` unless ``value`` is a real number (an int, a float, a 0-dim array / tensor).

    ``float("3")`` would accept the string ``"3"``: here a string, a bool or None is refused with the field's name.
    """
    if isinstance(value, bool | np.bool_ | str | bytes) or value is None:
        raise TypeError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
    try:
        float(value.detach() if hasattr(value, "detach") else value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r} ({type(value).__name__})") from None


def check_instance(value: Any, cls: type, name: str) -> None:
    """Raise TypeError naming ``name`` unless ``value`` is an instance of ``cls`` (the class itself is named)."""
    if isinstance(value, cls):
        return
    if value is cls:
        raise TypeError(f"{name} must be a {cls.__name__} instance, got the class itself: pass {cls.__name__}()")
    hint = f": build one from the mapping with {cls.__name__}(**mapping)" if isinstance(value, Mapping) else ""
    raise TypeError(f"{name} must be a {cls.__name__}, got {type(value).__name__}{hint}")

"""One way from plain values (a JSON file, a checkpoint header, a record) to a typed config.

:func:`config_from_dict` builds a (frozen) dataclass from a mapping by the dataclass's own field
types: nested config dataclasses from nested mappings, tuples from JSON lists, ``Literal`` modes
checked against their allowed values, ``Path`` from strings, ``X | None`` accepted as None. Unknown
keys are refused by name (a misspelt key must not be silently ignored), and the dataclass's own
``__post_init__`` then validates values. Every error is a ``ValueError`` that names the field.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def config_from_dict(cls: type[T], d: Mapping[str, Any], what: str | None = None) -> T:
    """``cls(**d)`` with nested dataclasses, tuples, ``Literal`` and ``Path`` fields converted
    by their annotations; ``what`` names the thing in errors (default: the class name)."""
    what = what or cls.__name__
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    if not isinstance(d, Mapping):
        raise ValueError(f"{what} must be a mapping of its fields, got {type(d).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(d) - set(fields))
    if unknown:
        raise ValueError(f"unknown {what} fields {unknown}; known: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {name: _convert(hints[name], value, f"{what}.{name}") for name, value in d.items()}
    try:
        return cls(**kwargs)
    except TypeError as exc:  # a required field missing
        raise ValueError(f"{what}: {exc}") from exc


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, where) if len(inner) == 1 else value
    if origin is typing.Literal:
        if value not in args:
            raise ValueError(f"{where} must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return value if isinstance(value, tp) else config_from_dict(tp, value, where)
    if origin is tuple and isinstance(value, (list, tuple)):
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ValueError(f"{where} must have {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value))) if args \
            else tuple(value)
    if tp is Path and isinstance(value, str):
        return Path(value)
    return value

"""Typed settings rebuilt from plain JSON data, every value's type and range checked.

A model file carries the proposal stage's settings (a3d.runtime.frontend.proposals.ProposalConfig) as
nested JSON objects. A damaged or foreign file must be refused when it is opened, with the
setting's name, not fail with a traceback deep inside the proposal stage on the first frame (a
string where a count belongs) or run out of memory there (a count of 10^30).

Rules: an ``int`` field takes a JSON integer (not a boolean) in [0, MAX_COUNT], a ``float`` field a
finite number >= 0 (every proposal setting is a count, a weight, a scale or a fraction), a
``bool`` a boolean, a ``tuple[X, ...]`` a non-empty list, a ``tuple[X, Y, Z]`` a list of exactly
that length, a dataclass an object without unknown keys (missing keys keep their defaults).
``tighter`` names fields with narrower ranges (e.g. a fraction in [0, 1], a count >= 1).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from a3d.runtime.errors import ModelError
from a3d.runtime.io.json_input import is_finite_number

MAX_COUNT = 10_000_000  # beyond any sensible count; stops a huge integer before it allocates
T = TypeVar("T")


def dataclass_from_plain(
    cls: type[T], values: Any, where: str, tighter: Mapping[str, tuple[float, float]] | None = None
) -> T:
    """``cls`` from ``values``; a ModelError "WHERE.key.path must be ..., got ..." at the first bad value.

    ``tighter`` maps a field name (at any depth) to its (low, high) bounds, both inclusive.
    """
    return _dataclass(cls, values, where, dict(tighter or {}))


def _dataclass(cls: type, values: Any, where: str, tighter: dict[str, tuple[float, float]]) -> Any:
    if not isinstance(values, Mapping):
        raise _bad(where, "an object", values)
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(str(k) for k in set(values) - known)
    if unknown:
        raise ModelError(f"{where}: unknown setting(s) {', '.join(unknown)}")
    built = {key: _value(hints[key], value, f"{where}.{key}", key, tighter) for key, value in values.items()}
    try:
        return cls(**built)
    except (TypeError, ValueError) as e:  # the dataclass's own checks
        raise ModelError(f"{where}: {e}") from None


def _value(hint: Any, value: Any, where: str, name: str, tighter: dict[str, tuple[float, float]]) -> Any:
    if dataclasses.is_dataclass(hint):
        return _dataclass(hint, value, where, tighter)
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        variadic = len(args) == 2 and args[1] is Ellipsis
        if not isinstance(value, list | tuple) or (len(value) == 0 if variadic else len(value) != len(args)):
            want = "a non-empty list" if variadic else f"a list of {len(args)} values"
            raise _bad(where, want, value)
        items = [args[0]] * len(value) if variadic else list(args)
        pairs = enumerate(zip(items, value, strict=True))
        return tuple(_value(h, v, f"{where}[{i}]", name, tighter) for i, (h, v) in pairs)
    if hint is bool:
        if not isinstance(value, bool):
            raise _bad(where, "true or false", value)
        return value
    if hint in (int, float):
        low, high = tighter.get(name, (0, MAX_COUNT if hint is int else math.inf))
        ok = is_finite_number(value) and (isinstance(value, int) or hint is float)
        if not ok or not low <= value <= high:
            kind = "an integer" if hint is int else "a finite number"
            bounds = f">= {low}" if math.isinf(high) else f"in [{low}, {high}]"
            raise _bad(where, f"{kind} {bounds}", value)
        return hint(value)
    if hint is str:
        if not isinstance(value, str):
            raise _bad(where, "a string", value)
        return value
    raise TypeError(f"{where}: no plain form for settings of type {hint!r}")  # a programming error


def _bad(where: str, want: str, value: Any) -> ModelError:
    return ModelError(f"{where} must be {want}, got {repr(value)[:60]}")

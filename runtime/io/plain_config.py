"""Typed settings to and from plain JSON data: the one codec of a3d's settings dataclasses.

Training configurations (a3d.train.config: presets, JSON/TOML files, ``--set``) and the settings a
model file carries (the proposal stage's a3d.runtime.frontend.proposals.ProposalConfig) go
through the same walker, so a setting has one name and one type on both sides. Every value's
type is checked against the dataclass field's; a bad value is a one-line error naming its dotted
path (``proposals.superpixels.n_segments must be ...``), never a traceback deep inside a stage.

Two policies:

- **strict** (``dataclass_from_plain``, for files a program wrote: model metadata): JSON types
  exactly; an ``int`` is a JSON integer (not a boolean) in [0, MAX_COUNT], a ``float`` a finite
  number >= 0 (a count of 10^30 is stopped before it allocates); a variadic tuple is non-empty;
  ``tighter`` narrows the range of named fields (e.g. a fraction in [0, 1]); a ModelError.
- **lenient** (``apply_plain(..., lenient=True)``, for what people type: config files and
  ``--set``): strings are read as what the field holds ("true", "0.5", "300,400" for a tuple),
  an integral float is an integer, ranges only where ``tighter`` gives them.

Both: a dataclass is an object without unknown keys, applied onto a base value (missing keys keep
it: the defaults, or a preset's values); ``tuple[X, Y]`` takes a list of exactly that length;
``X | None``, ``Literal[...]`` and nested dataclasses (also inside tuples) are supported.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from a3d.runtime.errors import ModelError
from a3d.runtime.io.json_input import is_finite_number

MAX_COUNT = 10_000_000  # beyond any sensible count; stops a huge integer before it allocates
T = TypeVar("T")
Limits = Mapping[str, tuple[float, float]]
_TRUE, _FALSE = ("true", "1", "yes"), ("false", "0", "no")


def dataclass_from_plain(cls: type[T], values: Any, where: str, tighter: Limits | None = None) -> T:
    """``cls`` (its defaults) with ``values`` applied, strictly; a ModelError "WHERE.key.path must be
    ..., got ..." at the first bad value. ``tighter`` maps a field name (at any depth) to its
    (low, high) bounds, both inclusive."""
    return apply_plain(cls(), values, where, tighter=tighter)


def apply_plain(
    base: T,
    values: Any,
    where: str = "",
    *,
    tighter: Limits | None = None,
    lenient: bool = False,
    error: type[ValueError] = ModelError,
) -> T:
    """A copy of dataclass ``base`` with the (nested) ``values`` applied under the strict or the
    lenient policy (module docstring); ``error`` "WHERE.path ..." at the first bad value.
    ``where`` is the dotted path of ``base`` itself ("" at the top)."""
    return _Decoder(dict(tighter or {}), lenient, error).dataclass(base, values, where)


def plain_from_dataclass(obj: Any) -> Any:
    """Dataclass tree -> JSON-ready dicts and lists (tuples as lists): what ``apply_plain`` reads."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: plain_from_dataclass(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, list | tuple):
        return [plain_from_dataclass(v) for v in obj]
    return obj


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


class _Decoder:
    def __init__(
        self, tighter: dict[str, tuple[float, float]], lenient: bool, error: type[ValueError]
    ) -> None:
        self.tighter, self.lenient, self.error = tighter, lenient, error

    def bad(self, where: str, want: str, value: Any) -> ValueError:
        return self.error(f"{where or 'settings'} must be {want}, got {repr(value)[:60]}")

    def dataclass(self, base: Any, values: Any, where: str) -> Any:
        if not isinstance(values, Mapping):
            raise self.bad(where, "an object", values)
        hints = typing.get_type_hints(type(base))
        names = [f.name for f in dataclasses.fields(base)]
        unknown = [_join(where, str(k)) for k in values if k not in names]
        if unknown:
            raise self.error(
                f"unknown setting(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(names))})"
            )
        changes = {
            key: self.value(hints[key], value, _join(where, key), key, getattr(base, key))
            for key, value in values.items()
        }
        try:
            return dataclasses.replace(base, **changes)
        except (TypeError, ValueError) as e:  # the dataclass's own checks
            raise self.error(f"{where or type(base).__name__}: {e}") from None

    def value(self, hint: Any, value: Any, where: str, name: str, current: Any = None) -> Any:
        origin, args = typing.get_origin(hint), typing.get_args(hint)
        if dataclasses.is_dataclass(hint):
            if isinstance(value, hint):
                return value
            return self.dataclass(current if isinstance(current, hint) else hint(), value, where)
        if origin in (typing.Union, types.UnionType):
            if value is None and type(None) in args:
                return None
            errors = []
            for arg in (a for a in args if a is not type(None)):
                try:
                    return self.value(arg, value, where, name, current)
                except ValueError as e:
                    errors.append(e)
            raise errors[0] if errors else self.bad(where, f"one of {args}", value)
        if origin in (tuple, list):
            return self.sequence(origin, args, value, where, name)
        if origin is typing.Literal:
            if value not in args:
                raise self.bad(where, f"one of {list(args)}", value)
            return value
        if hint is typing.Any:
            return value
        if hint is bool:
            return self.boolean(value, where)
        if hint in (int, float):
            return self.number(hint, value, where, name)
        if hint is str:
            if isinstance(value, str) or (
                self.lenient and isinstance(value, int | float) and not isinstance(value, bool)
            ):
                return str(value)
            raise self.bad(where, "a string", value)
        raise TypeError(f"{where}: no plain form for settings of type {hint!r}")  # a programming error

    def sequence(self, origin: type, args: tuple, value: Any, where: str, name: str) -> Any:
        if self.lenient and isinstance(value, str):
            value = [v for v in value.split(",") if v.strip()]
        variadic = origin is list or not args or (len(args) == 2 and args[1] is Ellipsis)
        if variadic:
            ok = isinstance(value, list | tuple) and (self.lenient or len(value) > 0)
            want = "a list" if self.lenient else "a non-empty list"
        else:
            ok = isinstance(value, list | tuple) and len(value) == len(args)
            want = f"a list of {len(args)} values"
        if not ok:
            raise self.bad(where, want, value)
        items = [args[0] if args else typing.Any] * len(value) if variadic else list(args)
        pairs = enumerate(zip(items, value, strict=True))
        return origin(self.value(h, v, f"{where}[{i}]", name) for i, (h, v) in pairs)

    def boolean(self, value: Any, where: str) -> bool:
        if isinstance(value, bool):
            return value
        if self.lenient and isinstance(value, str) and value.lower() in _TRUE + _FALSE:
            return value.lower() in _TRUE
        raise self.bad(where, "true or false", value)

    def number(self, hint: type, value: Any, where: str, name: str) -> int | float:
        kind = "an integer" if hint is int else "a finite number"
        if self.lenient and not isinstance(value, bool) and isinstance(value, str | int | float):
            try:
                number = float(value)
            except (ValueError, OverflowError):
                raise self.bad(where, kind, value) from None
            ok = math.isfinite(number) and (hint is float or number.is_integer())
            value = int(number) if ok and hint is int and not isinstance(value, int) else value
            value = float(value) if ok and hint is float else value
        else:
            ok = is_finite_number(value) and (isinstance(value, int) or hint is float)
        default = (-math.inf, math.inf) if self.lenient else (0, MAX_COUNT if hint is int else math.inf)
        low, high = self.tighter.get(name, default)
        if not ok or not low <= value <= high:
            if math.isinf(low) and math.isinf(high):
                raise self.bad(where, kind, value)
            bounds = f">= {low}" if math.isinf(high) else f"in [{low}, {high}]"
            raise self.bad(where, f"{kind} {bounds}", value)
        return hint(value)

"""Argument checks whose errors name the argument and what was expected (ValueError/TypeError).

Used by the Python APIs and, through ``sdfcommon.tooling.commands``'s config getters, by the entry points, so a
value is judged by one rule whichever way it arrives.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping, Sequence
from typing import Any, Optional, Union


def check_int(value: Any, name: str, minimum: Optional[int] = None, maximum: Optional[int] = None) -> int:
    """``value`` as an int, refusing bools, floats, strings and values outside [minimum, maximum].

    Raises:
        ValueError: ``"<name> must be an integer >= <minimum>, got <value!r>"`` (the bounds given).
    """
    if isinstance(value, bool) or not isinstance(value, int) or (minimum is not None and value < minimum) or (
            maximum is not None and value > maximum):
        raise ValueError(f"{name} must be an integer{_bounds(minimum, maximum)}, got {value!r}")
    return int(value)


def check_float(value: Any, name: str, minimum: Optional[float] = None, maximum: Optional[float] = None) -> float:
    """``value`` (an int or a float, not a bool) as a finite float within [minimum, maximum].

    Raises:
        ValueError: ``"<name> must be a number >= <minimum>, got <value!r>"`` (the bounds given).
    """
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    if not ok or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be a finite number{_bounds(minimum, maximum)}, got {value!r}")
    return float(value)


def _bounds(minimum, maximum) -> str:
    if minimum is not None and maximum is not None:
        return f" in [{minimum}, {maximum}]"
    if minimum is not None:
        return f" >= {minimum}"
    return f" <= {maximum}" if maximum is not None else ""


# ------------------------------------------------------------------------------------------------
# Dataclass fields against their annotations (settings built from configs by hydra)


def _describe(hint: Any) -> str:
    """A reader's name for a type annotation: float -> "a number", Optional[int] -> "an integer or null"."""
    origin = typing.get_origin(hint)
    if origin is Union:
        return " or ".join(_describe(a) for a in typing.get_args(hint))
    if origin in (list, tuple, Sequence) or hint in (list, tuple):
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        return "a list" + (f" of ({', '.join(sorted(set(_describe(a) for a in args)))})" if args else "")
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(hint))
    return {float: "a number", int: "an integer", bool: "true or false", str: "a string",
            type(None): "null"}.get(hint, getattr(hint, "__name__", str(hint)))


def _matches(value: Any, hint: Any) -> bool:
    """Whether ``value`` (plain Python, as a config gives it) fits ``hint``; unknown kinds of
    annotation (classes, callables) are not judged."""
    if hint is Any:
        return True
    origin = typing.get_origin(hint)
    if origin is Union:
        return any(_matches(value, a) for a in typing.get_args(hint))
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    if origin in (list, tuple, Sequence) or hint in (list, tuple):
        if not isinstance(value, (list, tuple)):
            return False
        args = typing.get_args(hint)
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(args) == len(value) and all(_matches(v, a) for v, a in zip(value, args))
        return not args or all(_matches(v, args[0]) for v in value)
    if hint is type(None) or hint is None:
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint in (bool, str):
        return isinstance(value, hint)
    return True


def check_field_types(cls: type, values: Mapping[str, Any], name: str = "") -> None:
    """Checks keyword arguments for a dataclass against its field annotations before it is built,
    so that ``optim.lr=fast`` is reported as such and not by whatever comparison meets it first.

    Args:
        cls: the dataclass (not a dataclass: nothing is checked).
        values: field name -> plain Python value (unknown names are left to the constructor).
        name: the prefix of the messages (e.g. the config key "optim").
    Raises:
        TypeError: ``"<name>.<field> must be <expected>, got <value!r>"``.
    """
    if not dataclasses.is_dataclass(cls):
        return
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in values and f.name in hints and not _matches(values[f.name], hints[f.name]):
            key = f"{name}.{f.name}" if name else f.name
            raise TypeError(f"{key} must be {_describe(hints[f.name])}, got {values[f.name]!r}")


__all__ = ["check_int", "check_float", "check_field_types"]

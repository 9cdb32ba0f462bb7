"""The project's one argument-checking module: each check raises a ValueError or TypeError in one
format, ``"<name> must be <expected>, got <value!r>"`` (shapes: ``"<name> must have shape (B, N, N, N),
got (2, 3)"``), and returns the value it judged. Used by the Python APIs and, through
``sdfcommon.tooling.commands``'s config getters, by the entry points, so a value is judged by one rule
whichever way it arrives. It imports no torch: a tensor check asks only whether torch is loaded.
"""
from __future__ import annotations

import dataclasses
import math
import re
import sys
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
        ValueError: ``"<name> must be a finite number >= <minimum>, got <value!r>"`` (the bounds given).
    """
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    if not ok or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be a finite number{_bounds(minimum, maximum)}, got {value!r}")
    return float(value)


def check_positive(value: Any, name: str) -> float:
    """``value`` as a float (anything ``float()`` takes: ints, numpy scalars, one-element tensors),
    refusing what is not positive and finite.

    Raises:
        ValueError: ``"<name> must be a positive finite number, got <value!r>"``.
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def check_int_sequence(values: Any, name: str, minimum: Optional[int] = None, maximum: Optional[int] = None,
                       allow_empty: bool = False) -> tuple[int, ...]:
    """``values`` (any iterable) as a tuple of ints, each judged as ``check_int`` judges one; empty
    only with ``allow_empty``.

    Raises:
        ValueError: ``"<name> must be a non-empty sequence of integers >= <minimum>, got <values!r>"``.
    """
    try:
        out = tuple(values)
    except TypeError:
        out = None
    if out is None or (not out and not allow_empty) or any(
            isinstance(v, bool) or not isinstance(v, int) or (minimum is not None and v < minimum)
            or (maximum is not None and v > maximum) for v in out):
        raise ValueError(f"{name} must be a {'' if allow_empty else 'non-empty '}sequence of integers"
                         f"{_bounds(minimum, maximum)}, got {values!r}")
    return tuple(int(v) for v in out)


def check_instance(value: Any, name: str, cls: Union[type, tuple[type, ...]], expected: str = "") -> Any:
    """``value`` when it is an instance of ``cls``.

    Raises:
        TypeError: ``"<name> must be <expected>, got <type>"`` (``expected`` defaults to ``a <cls name>``).
    """
    if not isinstance(value, cls):
        expected = expected or " or ".join(f"a {c.__name__}" for c in (cls if isinstance(cls, tuple) else (cls,)))
        raise TypeError(f"{name} must be {expected}, got {type(value).__name__}")
    return value


def _bounds(minimum, maximum) -> str:
    if minimum is not None and maximum is not None:
        return f" in [{minimum}, {maximum}]"
    if minimum is not None:
        return f" >= {minimum}"
    return f" <= {maximum}" if maximum is not None else ""


# ------------------------------------------------------------------------------------------------
# Shapes of arrays and tensors


def _shape_matches(shape: tuple[int, ...], pattern: str, at_least: Mapping[str, int]) -> Optional[dict[str, int]]:
    """The sizes the letters of ``pattern`` ("B, N, N, N", "..., R, R, R", "V, 3") take in
    ``shape``, or None when it does not fit (a letter is one size wherever it appears)."""
    dims = [d.strip() for d in pattern.split(",") if d.strip()]
    if dims and "..." in (dims[0], dims[-1]):
        leading = dims[0] == "..."
        dims = dims[1:] if leading else dims[:-1]
        if len(shape) < len(dims):
            return None
        shape = shape[len(shape) - len(dims):] if leading else shape[:len(dims)]
    elif len(shape) != len(dims):
        return None
    sizes: dict[str, int] = {}
    for dim, size in zip(dims, shape):
        if re.fullmatch(r"\d+", dim):
            if size != int(dim):
                return None
        elif sizes.setdefault(dim, size) != size or size < at_least.get(dim, 0):
            return None
    return sizes


def check_shape(value: Any, name: str, *shapes: str, at_least: Optional[Mapping[str, int]] = None) -> dict[str, int]:
    """The sizes of ``value``'s shape (a numpy array, a torch tensor: anything with ``.shape``) by
    the letters of the first of ``shapes`` it fits, e.g. ``check_shape(sdf, "sdf", "B, N, N, N",
    at_least={"N": 3})`` -> ``{"B": 2, "N": 16}``. Numbers are fixed sizes, a leading (or trailing)
    ``...`` takes any leading (trailing) axes, ``at_least`` gives the smallest size of a letter.

    Raises:
        TypeError: ``"<name> must be an array or tensor, got <type>"`` (no shape).
        ValueError: ``"<name> must have shape (B, N, N, N) with N >= 3, got (2, 3)"``.
    """
    shape = getattr(value, "shape", None)
    if not isinstance(shape, tuple):
        raise TypeError(f"{name} must be an array or tensor, got {type(value).__name__}")
    at_least = at_least or {}
    for pattern in shapes:
        sizes = _shape_matches(tuple(shape), pattern, at_least)
        if sizes is not None:
            return sizes
    by_limit: dict[int, list[str]] = {}
    for letter, limit in at_least.items():
        by_limit.setdefault(limit, []).append(letter)
    limits = " and ".join(f"{', '.join(letters)} >= {limit}" for limit, letters in by_limit.items())
    expected = " or ".join(f"({p})" for p in shapes) + (f" with {limits}" if limits else "")
    raise ValueError(f"{name} must have shape {expected}, got {tuple(shape)}")


def check_tensor(value: Any, name: str, *shapes: str, at_least: Optional[Mapping[str, int]] = None,
                 floating: bool = False) -> dict[str, int]:
    """``check_shape`` for a torch tensor (floating point with ``floating``); returns its sizes.

    Raises:
        TypeError: ``"<name> must be a torch.Tensor, got <type>"``, ``"<name> must be a floating-point
            tensor, got <dtype>"``.
        ValueError: as ``check_shape``.
    """
    torch = sys.modules.get("torch")  # not loaded: value cannot be a tensor, and this module stays light
    if torch is None or not isinstance(value, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    sizes = check_shape(value, name, *shapes, at_least=at_least) if shapes else {}
    if floating and not value.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {value.dtype}")
    return sizes


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


__all__ = ["check_int", "check_float", "check_positive", "check_int_sequence", "check_instance", "check_shape", "check_tensor",
           "check_field_types"]

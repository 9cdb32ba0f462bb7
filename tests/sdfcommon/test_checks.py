"""The argument checks of ``sdfcommon.tooling.checks``: what each accepts (and returns), what it
refuses, and the exact message, ``"<name> must be <expected>, got <value!r>"``."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Literal, Optional

import numpy as np
import pytest
import torch

from sdfcommon.tooling.checks import (
    check_field_types,
    check_float,
    check_instance,
    check_int,
    check_int_sequence,
    check_positive,
    check_shape,
    check_tensor,
)


def raises(kind: type, message: str):
    """pytest.raises for exactly this message (not a pattern)."""
    return pytest.raises(kind, match="^" + re.escape(message) + "$")


# ------------------------------------------------------------------------------------------------
# check_int


@pytest.mark.parametrize("value, kwargs", [(0, {}), (-7, {}), (3, {"minimum": 3}), (3, {"maximum": 3}),
                                           (2, {"minimum": 1, "maximum": 3})])
def test_check_int_accepts_ints_within_the_bounds(value, kwargs):
    out = check_int(value, "n", **kwargs)
    assert out == value and type(out) is int


@pytest.mark.parametrize("value, kwargs, message", [
    (True, {}, "n must be an integer, got True"),
    (False, {"minimum": 0}, "n must be an integer >= 0, got False"),
    (2.0, {}, "n must be an integer, got 2.0"),
    ("3", {}, "n must be an integer, got '3'"),
    (None, {}, "n must be an integer, got None"),
    (0, {"minimum": 1}, "n must be an integer >= 1, got 0"),
    (4, {"maximum": 3}, "n must be an integer <= 3, got 4"),
    (5, {"minimum": 1, "maximum": 3}, "n must be an integer in [1, 3], got 5"),
    (0, {"minimum": 1, "maximum": 3}, "n must be an integer in [1, 3], got 0"),
])
def test_check_int_refuses(value, kwargs, message):
    with raises(ValueError, message):
        check_int(value, "n", **kwargs)


# ------------------------------------------------------------------------------------------------
# check_float


@pytest.mark.parametrize("value, kwargs", [(0.5, {}), (2, {}), (-1e300, {}), (0.0, {"minimum": 0.0}),
                                           (1, {"minimum": 0, "maximum": 1})])
def test_check_float_accepts_finite_numbers_within_the_bounds(value, kwargs):
    out = check_float(value, "x", **kwargs)
    assert out == value and type(out) is float


@pytest.mark.parametrize("value, kwargs, message", [
    (True, {}, "x must be a finite number, got True"),
    (math.inf, {}, "x must be a finite number, got inf"),
    (-math.inf, {"minimum": 0}, "x must be a finite number >= 0, got -inf"),
    (math.nan, {}, "x must be a finite number, got nan"),
    ("0.5", {}, "x must be a finite number, got '0.5'"),
    (None, {}, "x must be a finite number, got None"),
    (-0.1, {"minimum": 0.0}, "x must be a finite number >= 0.0, got -0.1"),
    (2.5, {"maximum": 2}, "x must be a finite number <= 2, got 2.5"),
    (1.5, {"minimum": 0, "maximum": 1}, "x must be a finite number in [0, 1], got 1.5"),
])
def test_check_float_refuses(value, kwargs, message):
    with raises(ValueError, message):
        check_float(value, "x", **kwargs)


# ------------------------------------------------------------------------------------------------
# check_positive


@pytest.mark.parametrize("value, expected", [(1, 1.0), (0.25, 0.25), (np.float32(0.5), 0.5),
                                             (np.int64(3), 3.0), (torch.tensor([2.0]), 2.0)])
def test_check_positive_accepts_what_float_takes(value, expected):
    out = check_positive(value, "sigma")
    assert out == expected and type(out) is float


@pytest.mark.parametrize("value, shown", [(0, "0"), (-1.5, "-1.5"), (math.inf, "inf"), (math.nan, "nan"),
                                          (None, "None"), ("abc", "'abc'"), ([1.0, 2.0], "[1.0, 2.0]")])
def test_check_positive_refuses(value, shown):
    with raises(ValueError, f"sigma must be a positive finite number, got {shown}"):
        check_positive(value, "sigma")


# ------------------------------------------------------------------------------------------------
# check_int_sequence


@pytest.mark.parametrize("values, kwargs, expected", [
    ([1, 2], {}, (1, 2)),
    ((3,), {"minimum": 3}, (3,)),
    (range(3), {}, (0, 1, 2)),
    ([], {"allow_empty": True}, ()),
    ([1, 4], {"minimum": 1, "maximum": 4}, (1, 4)),
])
def test_check_int_sequence_accepts(values, kwargs, expected):
    out = check_int_sequence(values, "sizes", **kwargs)
    assert out == expected and type(out) is tuple


@pytest.mark.parametrize("values, kwargs, message", [
    ([], {}, "sizes must be a non-empty sequence of integers, got []"),
    (5, {}, "sizes must be a non-empty sequence of integers, got 5"),
    ([1, True], {}, "sizes must be a non-empty sequence of integers, got [1, True]"),
    ([1, 2.0], {}, "sizes must be a non-empty sequence of integers, got [1, 2.0]"),
    ([0, 1], {"minimum": 1}, "sizes must be a non-empty sequence of integers >= 1, got [0, 1]"),
    ([1, 9], {"minimum": 1, "maximum": 8}, "sizes must be a non-empty sequence of integers in [1, 8], got [1, 9]"),
    ([1.5], {"allow_empty": True}, "sizes must be a sequence of integers, got [1.5]"),
])
def test_check_int_sequence_refuses(values, kwargs, message):
    with raises(ValueError, message):
        check_int_sequence(values, "sizes", **kwargs)


# ------------------------------------------------------------------------------------------------
# check_instance


def test_check_instance_returns_the_value():
    value = [1]
    assert check_instance(value, "x", list) is value
    assert check_instance(2.0, "x", (int, float)) == 2.0


@pytest.mark.parametrize("value, cls, expected, message", [
    (1, str, "", "x must be a str, got int"),
    ("a", (int, float), "", "x must be a int or a float, got str"),
    (None, dict, "a mapping of settings", "x must be a mapping of settings, got NoneType"),
])
def test_check_instance_refuses(value, cls, expected, message):
    with raises(TypeError, message):
        check_instance(value, "x", cls, expected)


# ------------------------------------------------------------------------------------------------
# check_shape


@pytest.mark.parametrize("shape, patterns, at_least, expected", [
    ((2, 16, 16, 16), ("B, N, N, N",), None, {"B": 2, "N": 16}),
    ((2, 16, 16, 16), ("B, N, N, N",), {"N": 3}, {"B": 2, "N": 16}),
    ((5, 3), ("N, 3",), None, {"N": 5}),
    ((3,), ("N, 3", "3"), None, {}),                       # the second alternative fits
    ((4, 3), ("N, 3", "3"), None, {"N": 4}),               # the first that fits wins
    ((7, 2, 4, 4, 4), ("..., R, R, R",), None, {"R": 4}),  # leading axes, any number
    ((4, 4, 4), ("..., R, R, R",), None, {"R": 4}),        # ... may take no axis
    ((2, 7, 9), ("B, ...",), None, {"B": 2}),              # trailing axes
])
def test_check_shape_returns_the_letters_sizes(shape, patterns, at_least, expected):
    assert check_shape(np.zeros(shape), "x", *patterns, at_least=at_least) == expected


def test_check_shape_reads_tensors_too():
    assert check_shape(torch.zeros(2, 3), "x", "B, 3") == {"B": 2}


@pytest.mark.parametrize("shape, patterns, at_least, message", [
    ((2, 16, 16, 8), ("B, N, N, N",), None, "sdf must have shape (B, N, N, N), got (2, 16, 16, 8)"),
    ((2, 16, 16), ("B, N, N, N",), None, "sdf must have shape (B, N, N, N), got (2, 16, 16)"),
    ((2, 2, 2, 2), ("B, N, N, N",), {"N": 3}, "sdf must have shape (B, N, N, N) with N >= 3, got (2, 2, 2, 2)"),
    ((5, 4), ("N, 3", "3"), None, "sdf must have shape (N, 3) or (3), got (5, 4)"),
    ((4, 4), ("..., R, R, R",), None, "sdf must have shape (..., R, R, R), got (4, 4)"),
    ((3, 4, 5), ("..., R, R, R",), None, "sdf must have shape (..., R, R, R), got (3, 4, 5)"),
    ((1, 1), ("H, W",), {"H": 2, "W": 2}, "sdf must have shape (H, W) with H, W >= 2, got (1, 1)"),
    ((1, 1), ("H, W",), {"H": 2, "W": 3}, "sdf must have shape (H, W) with H >= 2 and W >= 3, got (1, 1)"),
])
def test_check_shape_refuses(shape, patterns, at_least, message):
    with raises(ValueError, message):
        check_shape(np.zeros(shape), "sdf", *patterns, at_least=at_least)


def test_check_shape_refuses_values_without_a_shape():
    with raises(TypeError, "sdf must be an array or tensor, got list"):
        check_shape([[0.0]], "sdf", "H, W")


# ------------------------------------------------------------------------------------------------
# check_tensor


def test_check_tensor_accepts_tensors():
    assert check_tensor(torch.zeros(2, 5, 3), "rays", "B, R, 3") == {"B": 2, "R": 5}
    assert check_tensor(torch.zeros(4, dtype=torch.int64), "index") == {}
    assert check_tensor(torch.zeros(4, dtype=torch.float64), "t", "R", floating=True) == {"R": 4}


@pytest.mark.parametrize("value, kwargs, kind, message", [
    (np.zeros((2, 3)), {}, TypeError, "rays must be a torch.Tensor, got ndarray"),
    ([1.0], {}, TypeError, "rays must be a torch.Tensor, got list"),
    (torch.zeros(2, dtype=torch.int64), {"floating": True}, TypeError,
     "rays must be a floating-point tensor, got torch.int64"),
    (torch.zeros(2, 4), {}, ValueError, "rays must have shape (R, 3), got (2, 4)"),
])
def test_check_tensor_refuses(value, kwargs, kind, message):
    shapes = ("R, 3",) if kind is ValueError else ()
    with raises(kind, message):
        check_tensor(value, "rays", *shapes, **kwargs)


# ------------------------------------------------------------------------------------------------
# check_field_types


@dataclass
class _Optim:
    lr: float = 1e-3
    steps: int = 10
    name: str = "adam"
    amsgrad: bool = False
    patience: Optional[int] = None
    sizes: list[int] = field(default_factory=lambda: [8, 16])
    pair: tuple[int, float] = (1, 0.5)
    mode: Literal["min", "max"] = "min"


def test_check_field_types_accepts_matching_values():
    check_field_types(_Optim, {"lr": 1, "steps": 3, "name": "sgd", "amsgrad": True, "patience": None,
                               "sizes": [1, 2], "pair": [2, 3], "mode": "max"}, "optim")
    check_field_types(_Optim, {"patience": 4, "sizes": ()})
    check_field_types(_Optim, {"unknown": "left to the constructor"})
    check_field_types(dict, {"lr": "not a dataclass: nothing is checked"})


@pytest.mark.parametrize("values, message", [
    ({"lr": "fast"}, "optim.lr must be a number, got 'fast'"),
    ({"lr": True}, "optim.lr must be a number, got True"),
    ({"steps": 2.0}, "optim.steps must be an integer, got 2.0"),
    ({"steps": False}, "optim.steps must be an integer, got False"),
    ({"name": 3}, "optim.name must be a string, got 3"),
    ({"amsgrad": "yes"}, "optim.amsgrad must be true or false, got 'yes'"),
    ({"patience": "x"}, "optim.patience must be an integer or null, got 'x'"),
    ({"sizes": [1, "a"]}, "optim.sizes must be a list of (an integer), got [1, 'a']"),
    ({"sizes": 8}, "optim.sizes must be a list of (an integer), got 8"),
    ({"pair": [1, 2, 3]}, "optim.pair must be a list of (a number, an integer), got [1, 2, 3]"),
    ({"mode": "avg"}, "optim.mode must be one of 'min', 'max', got 'avg'"),
])
def test_check_field_types_refuses(values, message):
    with raises(TypeError, message):
        check_field_types(_Optim, values, "optim")


def test_check_field_types_without_a_prefix_names_the_field():
    with raises(TypeError, "lr must be a number, got 'fast'"):
        check_field_types(_Optim, {"lr": "fast"})

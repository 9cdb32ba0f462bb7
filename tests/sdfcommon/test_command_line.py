"""How a command names itself in advice a user pastes (``invoked_as``)."""
from __future__ import annotations

import sys

import pytest

from sdfcommon.tooling.command_line import invoked_as


@pytest.mark.parametrize("orig_argv, argv, expected", [
    (["python", "train.py", "ckpt_path=x"], ["train.py", "ckpt_path=x"], "python train.py"),
    (["python", "../sdf/train.py"], ["../sdf/train.py"], "python ../sdf/train.py"),
    (["/venv/bin/python", "/venv/bin/sdfdiff-train", "a=1"], ["/venv/bin/sdfdiff-train", "a=1"], "sdfdiff-train"),
    (["python", "-m", "svr.train", "a=1"], ["/repo/svr/train.py", "a=1"], "python -m svr.train"),
    (["python", "-m", "pytest", "-q"], ["/venv/lib/pytest/__main__.py", "-q"], "FALLBACK"),
    (["python", "-c", "..."], ["-c"], "FALLBACK"),
])
def test_advice_repeats_the_way_the_command_was_started(monkeypatch, orig_argv, argv, expected):
    monkeypatch.setattr(sys, "orig_argv", orig_argv)
    monkeypatch.setattr(sys, "argv", argv)
    assert invoked_as("FALLBACK") == expected

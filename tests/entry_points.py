"""Calling hydra entry points in the test process, as their command lines would."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, Optional

import pytest


def run_entry(entry: Callable[[], None], args: list[str], monkeypatch) -> None:
    """Calls ``entry()`` (a ``sdfcommon.tooling.commands.hydra_entry`` main) with command-line ``args``."""
    monkeypatch.setattr(sys, "argv", ["prog", *args])
    entry()


def expect_usage_error(entry: Callable[[], None], args: list[str], monkeypatch, capsys,
                       prog: Optional[str] = None) -> str:
    """Runs ``entry`` and checks it stopped with exit status 2 and one line ``<prog>: error: ...``
    on stderr (warnings aside) and no traceback; returns that line."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        run_entry(entry, args, monkeypatch)
    err = capsys.readouterr().err
    assert stop.value.code == 2, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1, err[-3000:]
    assert prog is None or lines[0].startswith(f"{prog}: error: "), lines[0]
    return lines[0]


def files_under(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes), hidden ones included."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}

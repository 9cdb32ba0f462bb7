"""Reading PyTorch files safely: tensors and plain values only, errors that name the file.
``torch.load(weights_only=True)`` refuses a file that would run code; its message then advises
re-running with ``weights_only=False``, which runs whatever the file names. Our messages never pass
that advice on (``load_error_reason``).
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Union

# torch's weights-only failure: "Weights only load failed. ... Re-running `torch.load` with
# `weights_only` set to `False` will likely succeed, but it can result in arbitrary code execution.
# ... WeightsUnpickler error: <reason>\n\nCheck the documentation ... torch.load.html."
_WEIGHTS_ONLY = re.compile(r"Weights only load failed\..*?(?:WeightsUnpickler error:\s*(?P<reason>[^\n]*))?"
                           r"(?:\n.*?torch\.load\.html\.?|$)", re.DOTALL)


def load_error_reason(err: BaseException) -> str:
    """One line saying why ``torch.load`` failed, without torch's advice to load unsafely.

    Returns:
        e.g. ``"UnpicklingError: not plain tensors and values (Unsupported operand 227)"``.
    """
    text = scrub_unsafe_advice(str(err))
    line = next((s.strip() for s in text.splitlines() if s.strip()), "")
    return f"{type(err).__name__}: {line}" if line else type(err).__name__


def scrub_unsafe_advice(text: str) -> str:
    """``text`` with torch's weights-only failure (which advises ``weights_only=False``) replaced
    by its reason: for messages that wrap a ``torch.load`` error made elsewhere."""
    def short(match: re.Match) -> str:
        reason = (match.group("reason") or "").strip()
        return "not plain tensors and values" + (f" ({reason})" if reason else "")

    return _WEIGHTS_ONLY.sub(short, text)


def load_torch(path: Union[str, os.PathLike], map_location: Any = "cpu", what: str = "checkpoint") -> Any:
    """``torch.load(path, weights_only=True)``: tensors, numbers, strings, lists and dicts only.

    Args:
        what: how messages call the file ("checkpoint", "level checkpoint").
    Raises:
        FileNotFoundError naming the file; ValueError naming the file when it is a folder,
        truncated, corrupt or holds anything but plain values.
    """
    import torch  # heavy: this module stays light for the commands that load no tensors

    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{what} {p} is a folder, not a file")
    if not p.is_file():
        raise FileNotFoundError(f"{what} not found: {p}")
    try:
        return torch.load(p, map_location=map_location, weights_only=True)
    except Exception as err:  # torch raises many types for corrupt files
        raise ValueError(f"{p}: not a readable {what} ({load_error_reason(err)})") from None


__all__ = ["load_torch", "load_error_reason", "scrub_unsafe_advice"]

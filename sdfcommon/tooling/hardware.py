"""Settings that ask for hardware, judged against this machine before a command starts: a renderer
backend that cannot run here, or a CUDA GPU where torch sees none, is a ValueError naming the
setting (one line from a command), not a traceback once the work has begun. Used by the commands'
settings classes (``svr.inference.settings``, ``svr.training.settings``, ``mvr.settings``)."""
from __future__ import annotations

import torch

import renderer


def check_backend(backend: str, name: str = "backend") -> str:
    """``backend`` when the renderer's march can run it here (``renderer.backend_available``:
    "auto" and "reference" always can; "cpu" needs numba, "cuda" numba's CUDA target and a GPU).

    Raises:
        ValueError: ``"<name> must be one of ..."`` for an unknown name; ``"<name> 'cuda' cannot
            run here: <why> (auto picks one that can)"`` for one this machine cannot run.
    """
    try:
        if backend == "cuda" and not torch.cuda.is_available():
            ok, why = False, "torch sees no CUDA GPU"  # without loading the kernels first
        else:
            ok, why = renderer.backend_available(backend)
    except ValueError as err:  # "backend must be one of (...), got ..."
        raise ValueError(str(err).replace("backend", name, 1)) from None
    if not ok:
        raise ValueError(f"{name} {backend!r} cannot run here: {why} (auto picks one that can)")
    return backend


def check_cuda_devices(setting: str, count: int, instead: str) -> None:
    """Refuses ``setting`` (e.g. ``"trainer.accelerator='gpu'"``) when it needs ``count`` CUDA GPUs
    (-1: at least one) and torch sees fewer here.

    Args:
        setting: the setting as the message names it.
        count: GPUs it needs; -1 for "all of them" (at least one).
        instead: what to do instead, for the message (e.g. "train on the CPU with trainer=cpu").
    Raises:
        ValueError: ``"<setting> needs a CUDA GPU and torch sees none here: <instead>"`` (or names
            the counts).
    """
    have = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if have == 0:
        raise ValueError(f"{setting} needs a CUDA GPU and torch sees none here: {instead}")
    if count > have:
        raise ValueError(f"{setting} needs {count} CUDA GPUs and torch sees {have} here: {instead}")


__all__ = ["check_backend", "check_cuda_devices"]

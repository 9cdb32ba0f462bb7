"""Shared test set-up: skip `cuda` tests where no GPU is usable; quiet the fallback warning; Ctrl+C
for the tests that send it (``ctrl_c_raises``)."""
from __future__ import annotations

import signal
import warnings

import pytest
import torch


def _cuda_ok() -> bool:
    if not torch.cuda.is_available():
        return False
    try:
        import renderer

        return renderer.backend_available("cuda")[0]
    except Exception:
        return False


def pytest_collection_modifyitems(config, items):
    if _cuda_ok():
        return
    skip = pytest.mark.skip(reason="needs an NVIDIA GPU with numba CUDA")
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(autouse=True)
def _quiet_fallback():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="the fused .* kernels are unavailable")
        yield


@pytest.fixture
def umask_022():
    """Runs the test under umask 0o022 (files 0644, folders 0755 when created plainly), then restores
    the caller's umask."""
    import os

    previous = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(previous)


@pytest.fixture
def ctrl_c_raises():
    """Python's own SIGINT handler (Ctrl+C raises KeyboardInterrupt) for one test, the previous
    one restored after it: a shell starts a background job with SIGINT ignored, and Python then
    installs none, so a suite run from a background job would otherwise never see the interrupt."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)

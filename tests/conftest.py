"""Shared test set-up: the number of worker processes and OpenMP's idle policy for them; skip
`cuda` tests where no GPU is usable; quiet the fallback warning; Ctrl+C for the tests that send it
(``ctrl_c_raises``); the user's cache folder (``XDG_CACHE_HOME``, where commands run outside the
checkout put generated data) is a temporary folder for the whole session, for this process and
the commands it starts."""
from __future__ import annotations

import os
import shutil
import signal
import tempfile
import warnings

# The suite runs in several worker processes (pyproject.toml: -n auto), each with torch's and
# numba's threads on the shared OpenMP runtime: its idle threads must sleep rather than spin, or
# the workers take each other's cores. Read when the OpenMP library loads, so before torch.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest  # noqa: E402
import torch  # noqa: E402

MAX_WORKERS = 4  # each worker holds torch and numba (about 0.5 GiB); more rarely pays on one machine


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core this process may use, at most MAX_WORKERS."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_WORKERS))


def _cuda_ok() -> bool:
    if not torch.cuda.is_available():
        return False
    try:
        import renderer

        return renderer.backend_available("cuda")[0]
    except Exception:
        return False


def pytest_configure(config):
    folder = tempfile.mkdtemp(prefix="sdfdiff-test-cache-")
    config._sdfdiff_cache = (os.environ.get("XDG_CACHE_HOME"), folder)
    os.environ["XDG_CACHE_HOME"] = folder


def pytest_unconfigure(config):
    previous, folder = getattr(config, "_sdfdiff_cache", (None, None))
    if folder is None:
        return
    shutil.rmtree(folder, ignore_errors=True)
    if previous is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = previous


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

"""sdfcommon.tooling.processes: pools whose workers die with their parent also run the caller's initializer
(the procedural data generation's workers use one)."""
from __future__ import annotations

import os

from sdfcommon.tooling.processes import process_pool


def _set_marker(value: str) -> None:
    os.environ["SDFCOMMON_TEST_MARKER"] = value


def _marker_and_parent() -> tuple[str, int]:
    return os.environ.get("SDFCOMMON_TEST_MARKER", ""), os.getppid()


def test_pool_workers_run_the_initializer_after_the_parent_guard():
    with process_pool(2, initializer=_set_marker, initargs=("ready",)) as pool:
        results = [pool.submit(_marker_and_parent).result() for _ in range(4)]
    assert all(marker == "ready" and parent == os.getpid() for marker, parent in results)

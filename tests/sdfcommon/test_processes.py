"""sdfcommon.tooling.processes: pools whose workers die with their parent also run the caller's initializer
(the procedural data generation's workers use one); Ctrl+C ends the workers at once."""
from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time

import pytest

from sdfcommon.tooling.processes import OrderedJobs, map_unordered, process_pool


def _set_marker(value: str) -> None:
    os.environ["SDFCOMMON_TEST_MARKER"] = value


def _marker_and_parent() -> tuple[str, int]:
    return os.environ.get("SDFCOMMON_TEST_MARKER", ""), os.getppid()


def test_pool_workers_run_the_initializer_after_the_parent_guard():
    with process_pool(2, initializer=_set_marker, initargs=("ready",)) as pool:
        results = [pool.submit(_marker_and_parent).result() for _ in range(4)]
    assert all(marker == "ready" and parent == os.getpid() for marker, parent in results)


def _sleep(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_ctrl_c_ends_the_workers_instead_of_waiting_for_them(ctrl_c_raises):
    """Issue 40 item 16: before, the workers of a map stopped by Ctrl+C went on with the items in
    flight (here 30 s), and the process waited for them at exit."""
    main = threading.main_thread().ident
    threading.Timer(3.0, signal.pthread_kill, (main, signal.SIGINT)).start()  # Ctrl+C once the workers run
    with pytest.raises(KeyboardInterrupt):
        for _ in map_unordered(_sleep, [30.0, 30.0], 1):
            pass
    end = time.perf_counter() + 5.0
    while multiprocessing.active_children() and time.perf_counter() < end:
        time.sleep(0.05)
    assert not multiprocessing.active_children()


def _slow_square(x: int) -> tuple[int, str]:
    time.sleep(0.05 * (3 - x % 3))  # later jobs finish first
    return x * x, os.environ.get("SDFCOMMON_TEST_MARKER", "")


@pytest.mark.parametrize("workers", [0, 2])
def test_ordered_jobs_hand_over_every_result_in_submission_order(workers):
    seen = []
    with OrderedJobs(workers, lambda tag, result: seen.append((tag, result)), _set_marker, ("ready",)) as jobs:
        for x in range(7):
            jobs.submit(_slow_square, x, tag=f"job{x}")
            assert len(seen) >= (x + 1 if workers == 0 else x + 1 - 2 * workers)  # at most 2 per worker wait
    marker = "ready" if workers else os.environ.get("SDFCOMMON_TEST_MARKER", "")
    assert seen == [(f"job{x}", (x * x, marker)) for x in range(7)]


def test_ordered_jobs_left_by_an_exception_hand_over_nothing_more():
    seen = []
    with pytest.raises(RuntimeError, match="stop"):
        with OrderedJobs(1, lambda tag, result: seen.append(tag)) as jobs:
            for x in range(3):
                jobs.submit(_slow_square, x, tag=x)
            raise RuntimeError("stop")
    assert seen == [0]  # the third submit waited for the first; the others were dropped

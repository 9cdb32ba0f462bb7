"""Worker processes that die with their parent. A ``ProcessPoolExecutor``'s workers outlive a parent
killed by SIGTERM or SIGKILL: they wait on their call queue forever (seen: evaluation workers left
running, holding their memory). ``process_pool`` gives each worker two guards: on Linux the kernel
sends it SIGKILL when the parent dies (``prctl(PR_SET_PDEATHSIG)``), and everywhere a daemon thread
ends it once its parent is gone (its parent process id changes), checked every ``PARENT_POLL_S``
seconds.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator, Optional

PARENT_POLL_S = 1.0
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent_pid: int) -> None:
    """Makes this process end when ``parent_pid`` (its parent) ends; a pool's worker initializer.

    Safe to call where prctl does not exist (the watchdog thread still runs).
    """
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL))
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before the guard was set
        os._exit(1)

    def watch() -> None:
        while True:
            threading.Event().wait(PARENT_POLL_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()


def process_pool(workers: int, initializer: Optional[Callable[..., None]] = None,
                 initargs: tuple = ()) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (no fork of a parent holding threads and CUDA) that
    die with this process (``die_with_parent``), each then running ``initializer(*initargs)``."""
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_worker, initargs=(os.getpid(), initializer, tuple(initargs)))


def _start_worker(parent_pid: int, initializer: Optional[Callable[..., None]], initargs: tuple) -> None:
    die_with_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def default_workers() -> int:
    """Worker processes when none are given: one per core this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def map_unordered(fn: Callable[..., Any], items: Iterable[Any], workers: int, args: tuple = (),
                  initializer: Optional[Callable[..., None]] = None) -> Iterator[tuple[Any, Any]]:
    """``(item, fn(item, *args))`` for every item, in the order they finish: in this process when
    ``workers`` is 0, else in a ``process_pool`` of ``workers`` processes with at most two items per
    worker in flight (results are handled as they come, never all held at once). When the consumer
    stops or an item raises, the items not yet started are cancelled and the pool is shut down; on
    Ctrl+C (KeyboardInterrupt) or another exception that is no ``Exception`` the workers are ended
    at once."""
    if workers == 0:
        for item in items:
            yield item, fn(item, *args)
        return
    queue = list(items)
    queue.reverse()
    with process_pool(workers, initializer=initializer) as pool:  # workers die with this process
        running = {}
        try:
            while queue or running:
                while queue and len(running) < 2 * workers:
                    item = queue.pop()
                    running[pool.submit(fn, item, *args)] = item
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for job in finished:
                    yield running.pop(job), job.result()
        except BaseException as err:
            if not isinstance(err, (Exception, GeneratorExit)):
                # Ctrl+C or a signal's exception: the items in flight are abandoned, not awaited
                # (the shutdown below would wait for them to finish).
                for proc in list((getattr(pool, "_processes", None) or {}).values()):
                    proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise


class OrderedJobs:
    """Jobs whose results are handled in the order they were submitted: ``done(tag, fn(*args))``,
    run in this process at once when ``workers`` is 0, else in a ``process_pool`` of ``workers``
    processes (each running ``initializer(*initargs)`` first) while the caller prepares the next
    job, with at most two jobs per worker waiting. A context manager: leaving it normally hands
    over every result; leaving it by an exception cancels the jobs not yet started.
    """

    def __init__(self, workers: int, done: Callable[[Any, Any], None],
                 initializer: Optional[Callable[..., None]] = None, initargs: tuple = ()):
        self.workers, self.done = int(workers), done
        self.pool = process_pool(self.workers, initializer, initargs) if self.workers > 0 else None
        self.pending: deque = deque()

    def submit(self, fn: Callable[..., Any], *args: Any, tag: Any = None) -> None:
        if self.pool is None:
            self.done(tag, fn(*args))
            return
        self.pending.append((tag, self.pool.submit(fn, *args)))
        while len(self.pending) > 2 * self.workers:
            self._finish_one()

    def _finish_one(self) -> None:
        tag, job = self.pending.popleft()
        self.done(tag, job.result())

    def __enter__(self) -> "OrderedJobs":
        return self

    def __exit__(self, kind, err, trace) -> None:
        try:
            while kind is None and self.pending:
                self._finish_one()
        finally:
            if self.pool is not None:
                self.pool.shutdown(cancel_futures=True)


__all__ = ["OrderedJobs", "process_pool", "map_unordered", "default_workers", "die_with_parent", "PARENT_POLL_S"]

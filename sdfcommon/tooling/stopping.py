"""A command stopped by a signal, one path for Ctrl+C and SIGTERM: inside ``sigterm_as_interrupt``
SIGTERM raises ``Terminated``, a ``KeyboardInterrupt`` (as Ctrl+C raises one), so a command catches
``KeyboardInterrupt`` once, says in one line that it stopped and how to continue, and exits with
``128 + stop_signal(stop)`` (130 or 143, as a shell reports a process killed by that signal). Being
no ``Exception``, neither is taken by an ``except Exception`` for a failure of the work itself."""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


class Terminated(KeyboardInterrupt):
    """Raised in the main thread by ``sigterm_as_interrupt``'s handler when SIGTERM arrives."""

    signum = signal.SIGTERM


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Inside the block SIGTERM raises ``Terminated`` in the main thread; the previous handler is
    restored after it. Outside the main thread, where handlers cannot be set, it changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def stop_signal(stop: KeyboardInterrupt) -> int:
    """The signal that raised ``stop``: SIGTERM for ``Terminated``, else SIGINT (Ctrl+C)."""
    return int(getattr(stop, "signum", signal.SIGINT))


def stop_name(signum: int) -> str:
    """How a user knows the signal: "Ctrl+C (SIGINT)", "SIGTERM"."""
    return "Ctrl+C (SIGINT)" if signum == signal.SIGINT else signal.Signals(signum).name


__all__ = ["Terminated", "sigterm_as_interrupt", "stop_signal", "stop_name"]

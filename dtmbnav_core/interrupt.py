"""SIGINT and SIGTERM, handled the same way by the command line and the streaming receiver.

Ctrl-C (SIGINT) and ``kill`` or a service manager stopping the job (SIGTERM)
both end a run as an :class:`Interrupted` exception, so every ``finally`` and
every atomic writer (:func:`dtmbnav_core.h5io.atomic_path`) cleans up: no
hidden partial file is left behind. Python's default SIGTERM action would
kill the process on the spot instead.

A streaming receiver wants more than a clean abort: the frames it has
already received are worth keeping. :class:`DeferredStop` turns a signal
into a request that its loop honours between chunks, so a chunk is never
abandoned half-processed and nothing already read is dropped. A reader that
waits for input (a stalled pipe) polls :func:`stop_requested` and gives up
its wait when it is set.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from types import FrameType
from typing import Any

#: The signals that end a run.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """The run was stopped by SIGINT or SIGTERM.

    Attributes
    ----------
    signum : int
        The signal number.
    detail : str
        What was kept (e.g. the frames a receiver finalised), for the message.
    """

    def __init__(self, signum: int, detail: str = "") -> None:
        super().__init__(signum, detail)
        self.signum = int(signum)
        self.detail = detail

    @property
    def signal_name(self) -> str:
        """``"SIGINT"`` or ``"SIGTERM"``."""
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + its number (130, 143)."""
        return 128 + self.signum

    def __str__(self) -> str:
        return f"interrupted by {self.signal_name}" + (f"; {self.detail}" if self.detail else "")


@contextlib.contextmanager
def _handlers(handler: Callable[[int, FrameType | None], Any]) -> Iterator[bool]:
    """Install ``handler`` for :data:`STOP_SIGNALS`, restoring the previous ones after.

    Signal handlers can only be set from the main thread; elsewhere nothing is
    installed and the block runs with the process's handlers (yields False).
    """
    if threading.current_thread() is not threading.main_thread():
        yield False
        return
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield True
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old if old is not None else signal.SIG_DFL)


def _raise(signum: int, frame: FrameType | None) -> None:
    raise Interrupted(signum)


@contextlib.contextmanager
def interrupts_raise() -> Iterator[None]:
    """Inside the block SIGINT and SIGTERM raise :class:`Interrupted` (main thread only)."""
    with _handlers(_raise):
        yield


class DeferredStop:
    """SIGINT and SIGTERM as a stop request that a processing loop honours between items.

    Use as a context manager around the loop and iterate the input through
    :meth:`until_stopped`; while it is active, :func:`stop_requested` tells a
    blocking reader to give up. A second signal while a stop is pending
    raises :class:`Interrupted` at once (the user insists).

    Attributes
    ----------
    signum : int or None
        The first signal received, None while none has arrived.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> DeferredStop:
        global _active
        self._stack.enter_context(_handlers(self._handle))
        self._stack.callback(_set_active, _active)
        _active = self
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            raise Interrupted(signum)
        self.signum = signum

    def until_stopped(self, items: Iterable[Any]) -> Iterator[Any]:
        """Yield ``items`` until a stop is requested (checked before each item is asked for).

        An input whose ``ends_on_stop`` attribute is true ends by itself on a
        stop request after handing on what it had already read (e.g.
        :func:`receiver.reader.read_ahead`'s queue of blocks read from a pipe,
        which cannot be read again): it is drained, not cut short.
        """
        if getattr(items, "ends_on_stop", False):
            yield from items
            return
        iterator = iter(items)
        while self.signum is None:
            try:
                item = next(iterator)
            except StopIteration:
                return
            yield item


#: The innermost active :class:`DeferredStop`, None outside one.
_active: DeferredStop | None = None


def _set_active(stop: DeferredStop | None) -> None:
    global _active
    _active = stop


def stop_requested() -> bool:
    """Whether a stop is pending in an active :class:`DeferredStop`: a blocking wait for input should end."""
    return _active is not None and _active.signum is not None

"""Read ahead: the next IQ blocks are read and converted on a background thread while the receiver works.

Reading a block (``readinto``) and converting it to complex64 (numpy ufunc
loops) both release the GIL, so on a second core they overlap the
receiver's kernels; on one core they cost what they cost without the thread.
The queue between the two is bounded, so at most ``depth`` converted blocks
wait in memory whatever the capture's length.

A stop request (SIGINT, SIGTERM: :class:`dtmbnav_core.interrupt.DeferredStop`)
ends the reading. For a stream it does not end the hand-off: the blocks
already read are still yielded (a pipe's bytes cannot be read again), then
the iterator ends; a file's reader is cut short at once (its blocks can be
read again from the sample the receiver reports).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator

import numpy as np

from dtmbnav_core.interrupt import stop_requested

#: Blocks read ahead of the one the receiver is working on.
READ_AHEAD_BLOCKS = 2


class _End:
    """Queue marker: the source is exhausted (``error`` None) or raised ``error``."""

    def __init__(self, error: BaseException | None = None) -> None:
        self.error = error


class ReadAhead(Iterator[np.ndarray]):
    """The iterator :func:`read_ahead` returns; it ends by itself on a stop request, after what was read.

    Attributes
    ----------
    ends_on_stop : bool
        True tells :meth:`dtmbnav_core.interrupt.DeferredStop.until_stopped`
        to drain it rather than cut it short.
    """

    def __init__(self, items: Iterator[np.ndarray], ends_on_stop: bool) -> None:
        self._items = items
        self.ends_on_stop = ends_on_stop

    def __next__(self) -> np.ndarray:
        return next(self._items)

    def close(self) -> None:
        """Stop the reading thread (the consumer has gone)."""
        self._items.close()


def read_ahead(blocks: Iterable[np.ndarray], depth: int = READ_AHEAD_BLOCKS, *,
               keep_read_on_stop: bool = True) -> ReadAhead:
    """Yield the items of ``blocks``, produced on a background thread up to ``depth`` items ahead.

    An exception raised by ``blocks`` is re-raised here, in the consumer, at
    the point of the stream where it happened (blocks before it are yielded
    first). Closing the generator early (an error downstream) stops the
    thread without reading the rest of the source.

    Parameters
    ----------
    blocks : iterable of ndarray
        E.g. :meth:`receiver.capture.CaptureSource.chunks`.
    depth : int
        Items the thread may produce ahead of the consumer (>= 1).
    keep_read_on_stop : bool
        On a stop request, yield the blocks already read before ending (a
        stream's); False cuts the iterator short (a file's: module docstring).
    """
    if depth < 1:
        raise ValueError(f"depth must be >= 1, got {depth}")
    return ReadAhead(_handed_off(blocks, depth), keep_read_on_stop)


def _handed_off(blocks: Iterable[np.ndarray], depth: int) -> Iterator[np.ndarray]:
    """:func:`read_ahead`'s generator."""
    handoff: queue.Queue[np.ndarray | _End] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def offer(item: np.ndarray | _End) -> bool:
        """Queue ``item`` unless the consumer has gone; False when it has."""
        while not stop.is_set():
            try:
                handoff.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            source = iter(blocks)
            # A stop request ends the reading; what was read is handed on (module docstring).
            while not stop_requested():
                try:
                    block = next(source)
                except StopIteration:
                    break
                if not offer(block):
                    return
            offer(_End())
        except Exception as exc:  # noqa: BLE001 - handed to the consumer, which re-raises it
            offer(_End(exc))

    thread = threading.Thread(target=produce, name="iq-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            item = handoff.get()
            if isinstance(item, _End):
                if item.error is not None:
                    raise item.error
                return
            yield item
    finally:
        # The producer stops at its next hand-off; it is not waited for (a stalled pipe must not hang us).
        stop.set()

"""Read ahead: the next IQ blocks are read and converted on a background thread while the receiver works.

Reading a block (``readinto``) and converting it to complex64 (numpy ufunc
loops) both release the GIL, so on a second core they overlap the
receiver's kernels; on one core they cost what they cost without the thread.
The queue between the two is bounded, so at most ``depth`` converted blocks
wait in memory whatever the capture's length.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator

import numpy as np

#: Blocks read ahead of the one the receiver is working on.
READ_AHEAD_BLOCKS = 2


class _End:
    """Queue marker: the source is exhausted (``error`` None) or raised ``error``."""

    def __init__(self, error: BaseException | None = None) -> None:
        self.error = error


def read_ahead(blocks: Iterable[np.ndarray], depth: int = READ_AHEAD_BLOCKS) -> Iterator[np.ndarray]:
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
    """
    if depth < 1:
        raise ValueError(f"depth must be >= 1, got {depth}")
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
            for block in blocks:
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

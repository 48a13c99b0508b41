"""An in-process ``rtl_tcp`` server that replays cu8 bytes at real-time pace (tests, demos without a dongle).

:class:`RtlTcpReplay` listens on 127.0.0.1 (port 0: any free one), greets
each client as ``rtl_tcp`` does (:mod:`dtmbnav_core.rtltcp`), records every
command it receives, decoded, and streams the bytes from where the stream's
clock is: ``pace`` times real time from the first client's accept. A client
slower than that holds the server back (the bytes wait, none is lost), as a
pipe would; a dongle would drop them instead, which the receiver's drop
detection is for.

**Outage.** With ``drop_after_bytes`` or ``drop_after_s`` the server closes
the connection once, after exactly that many bytes (or the bytes of that
many stream seconds), waits ``outage_s`` before accepting again, and goes on
from where the clock says the stream is by then: the samples of the outage
are lost, as a dongle's would be. :attr:`RtlTcpReplay.outages` says which.

**End.** Without ``loop`` the server closes the connection after the last
byte and stops listening (a client's reconnects are refused);
:attr:`RtlTcpReplay.finished` is then set.
"""

from __future__ import annotations

import math
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import numpy as np

from dtmbnav_core import rtltcp

#: Bytes sent at a time, as ``rtl_tcp`` hands on the dongle's USB transfers (librtlsdr's default buffer of
#: 16 x 32 x 512 bytes): a block goes out once the clock has reached its last byte.
BLOCK_BYTES = 16 * 32 * 512
#: Seconds a blocked send or an idle wait lasts before the server checks whether it must stop.
POLL_S = 0.05
#: The greeting's tuner when none is given: an R820T with its 29 gain steps (the common RTL-SDR dongle).
DEFAULT_TUNER = (rtltcp.TUNER_NAMES.index("R820T"), 29)


@dataclass(frozen=True)
class ReplayOutage:
    """A connection the server closed on purpose.

    Attributes
    ----------
    at_byte : int
        Stream bytes sent before it.
    resumed_byte : int
        Stream byte the next connection started with.
    """

    at_byte: int
    resumed_byte: int

    @property
    def lost_samples(self) -> int:
        """I/Q pairs never sent."""
        return (self.resumed_byte - self.at_byte) // 2


class RtlTcpReplay:
    """A threaded rtl_tcp server replaying cu8 bytes (module docstring); a context manager.

    Parameters
    ----------
    samples : path, bytes or uint8 ndarray
        Interleaved cu8 I/Q (a raw file or a SigMF ``.sigmf-data``; its
        ``header_bytes`` are not skipped).
    sample_rate_hz : float
        The stream's sample rate.
    pace : float
        Stream seconds sent per second (tests: >> 1; ``math.inf``: as fast as the client takes them).
    loop : bool
        Start again at the first byte after the last.
    drop_after_bytes, drop_after_s : int or float, optional
        Close the connection once after this many stream bytes (rounded down
        to whole I/Q pairs) or stream seconds.
    outage_s : float
        Seconds the server waits after that close before accepting again.
    greeting : bytes, optional
        The first bytes sent to a client (default: ``RTL0``, an R820T).
    host, port : str, int
        Where to listen (port 0: a free one; :attr:`port` says which).

    Attributes
    ----------
    commands : list of (Command or int, int)
        Every command received, decoded, in order (all connections).
    connections : int
        Clients accepted.
    outages : list of ReplayOutage
    sent_bytes : int
        Stream bytes sent so far (all connections).
    finished : threading.Event
        Set when the last byte has been sent (without ``loop``).
    """

    def __init__(self, samples: str | Path | bytes | np.ndarray, sample_rate_hz: float, *, pace: float = 1.0,
                 loop: bool = False, drop_after_bytes: int | None = None, drop_after_s: float | None = None,
                 outage_s: float = 0.0, greeting: bytes | None = None, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        if isinstance(samples, (str, Path)):   # mapped, not read: a long capture need not fit in memory
            self._data = np.memmap(samples, np.uint8, "r")
        elif isinstance(samples, np.ndarray):
            self._data = samples.view(np.uint8).ravel()
        else:
            self._data = np.frombuffer(samples, np.uint8)
        if len(self._data) < 2:
            raise ValueError("rtl_tcp replay: no samples")
        if not pace > 0 or not sample_rate_hz > 0:
            raise ValueError(f"rtl_tcp replay: pace and sample rate must be positive, got {pace}, {sample_rate_hz}")
        self.bytes_per_s = 2.0 * sample_rate_hz * pace
        self.loop = loop
        if drop_after_s is not None:
            drop_after_bytes = int(drop_after_s * 2.0 * sample_rate_hz)
        self._drop_at = None if drop_after_bytes is None else drop_after_bytes - drop_after_bytes % 2
        self.outage_s = outage_s
        self._greeting = greeting if greeting is not None else rtltcp.Greeting(*DEFAULT_TUNER).encode()
        self.commands: list[tuple[rtltcp.Command | int, int]] = []
        self.connections = 0
        self.outages: list[ReplayOutage] = []
        self.sent_bytes = 0
        self.finished = threading.Event()
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(POLL_S)
        self.host, self.port = self._listener.getsockname()[:2]
        self._start_t: float | None = None
        self._thread = threading.Thread(target=self._serve, name="rtl_tcp-replay", daemon=True)

    @property
    def url(self) -> str:
        """``rtl_tcp://HOST:PORT`` of this server."""
        return f"rtl_tcp://{self.host}:{self.port}"

    def start(self) -> RtlTcpReplay:
        """Start serving (on a background thread)."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Close every socket and end the thread."""
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join()
        self._listener.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def received(self, command: rtltcp.Command) -> list[int]:
        """The values received for ``command``, in order."""
        with self._lock:
            return [value for c, value in self.commands if c == command]

    def _clock_byte(self) -> int:
        """Stream byte the clock says is due now (whole I/Q pairs)."""
        assert self._start_t is not None
        if math.isinf(self.bytes_per_s):   # pace inf: every byte is due (as fast as the client takes them)
            return sys.maxsize - 1
        due = int((time.monotonic() - self._start_t) * self.bytes_per_s)
        return due - due % 2

    def _serve(self) -> None:
        while not self._stopping.is_set() and not self.finished.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:   # the listener was closed
                return
            with conn:
                self._client(conn)
        self._listener.close()

    def _client(self, conn: socket.socket) -> None:
        """Greet, then stream until the end, a planned drop, a client that went away, or a stop."""
        self.connections += 1
        conn.settimeout(POLL_S)
        try:
            conn.sendall(self._greeting)
        except OSError:   # the client left before its greeting (it timed out waiting)
            return
        reader = threading.Thread(target=self._read_commands, args=(conn,), name="rtl_tcp-replay-commands",
                                  daemon=True)
        reader.start()
        if self._start_t is None:
            self._start_t = time.monotonic()
        elif self.outages and self.outages[-1].resumed_byte < 0:   # the clock moved on during the outage
            resumed = max(self.sent_bytes, self._clock_byte())
            self.outages[-1] = ReplayOutage(self.outages[-1].at_byte, resumed)
            self.sent_bytes = resumed
        try:
            self._stream(conn)
        except OSError:   # the client went away: wait for the next one
            pass
        finally:
            try:   # ends the command reader's wait; a FIN after the bytes sent, not a reset
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            reader.join()

    def _stream(self, conn: socket.socket) -> None:
        """Send block by block, each once the clock has reached its last byte, up to the end or a planned drop."""
        total = len(self._data) - len(self._data) % 2
        while not self._stopping.is_set():
            limit = min(math.inf if self.loop else total, math.inf if self._drop_at is None else self._drop_at)
            if self.sent_bytes >= limit:
                if self._drop_at is not None and self.sent_bytes >= self._drop_at:
                    self._drop_at = None
                    self.outages.append(ReplayOutage(self.sent_bytes, -1))
                    conn.shutdown(socket.SHUT_RDWR)
                    self._stopping.wait(self.outage_s)
                else:
                    self.finished.set()
                return
            block_end = int(min(self.sent_bytes + BLOCK_BYTES, limit))
            early_s = (block_end - self._clock_byte()) / self.bytes_per_s
            if early_s > 0:
                time.sleep(min(early_s, POLL_S))
                continue
            while self.sent_bytes < block_end:
                start = self.sent_bytes % total
                piece = self._data[start:start + min(block_end - self.sent_bytes, total - start)]
                sent = self._send(conn, memoryview(piece))
                self.sent_bytes += sent
                if sent < len(piece):   # a stop while blocked
                    return

    def _send(self, conn: socket.socket, view: memoryview) -> int:
        """Send ``view``, waiting while the client is slow; the bytes sent (fewer only on a stop)."""
        sent = 0
        while sent < len(view) and not self._stopping.is_set():
            try:
                sent += conn.send(view[sent:])
            except TimeoutError:
                continue
        return sent

    def _read_commands(self, conn: socket.socket) -> None:
        """Record the client's commands until it or the server closes the connection."""
        pending = b""
        while not self._stopping.is_set():
            try:
                part = conn.recv(64)
            except TimeoutError:
                continue
            except OSError:
                return
            if not part:
                return
            pending += part
            while len(pending) >= rtltcp.COMMAND.size:
                command = rtltcp.decode_command(pending[:rtltcp.COMMAND.size])
                pending = pending[rtltcp.COMMAND.size:]
                with self._lock:
                    self.commands.append(command)

"""An RTL-SDR over the network: a client of osmocom rtl-sdr's ``rtl_tcp`` as a capture source.

:class:`RtlTcpSource` stands in for :class:`receiver.capture.CaptureSource`
wherever the receiver reads a stream (``is_stream`` is true, ``chunks(n)``
yields complex64 blocks, decoded by the capture reader's own cu8 code). It
connects, reads the server's greeting, sends the settings (frequency
correction, sample rate, centre frequency, gain mode and gain: the bytes of
:mod:`dtmbnav_core.rtltcp`), drops what arrives while they take effect, and
streams. It is written on a plain socket: pyrtlsdr's ``RtlSdrTcpClient``
speaks pyrtlsdr's own server protocol, not ``rtl_tcp``'s.

**A lost connection** (the server closes it, a reset, no data for
:attr:`LinkPolicy.recv_timeout_s`) is a gap, never the end of the run: the
source reconnects with a doubling back-off (:attr:`LinkPolicy.reconnects`
tries), sends the settings again and goes on. The receiver's time base is
the sample count, so the samples the outage cost are handed on as zeros,
up to the stream index of the first sample after it on the host's clock (at
most :attr:`LinkPolicy.max_fill_s`). Sampling times come from arrivals: the
newest sample read was sampled no later than it arrived, so each read bounds
when the first sample of the stream (and the first after a gap) was
sampled, and the earliest bound, the one with the least network and USB
latency, is kept. On the zeros the receiver loses its lock and flags the
first frame of its next lock ``GAP`` (:mod:`receiver.pipeline`); after an
outage shorter than :data:`receiver.drops.MAX_BRIDGE_S` whose zeros fall a
sample or more short, its drop detector measures the rest and bridges it
instead (``DROP``, the segment goes on). Every frame before the gap is kept. Each outage is recorded (:class:`Outage`, the ``outage_*``
attributes of :meth:`RtlTcpSource.attributes`). When no reconnect succeeds
the stream has ended: the source returns, and says why (``rtl_tcp_end``).

**A stop request** (SIGINT, SIGTERM: :class:`dtmbnav_core.interrupt.DeferredStop`)
ends the stream after the samples already read from the socket are handed on.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Self
from urllib.parse import urlsplit

import numpy as np

from dtmbnav_core import rtltcp
from dtmbnav_core.interrupt import stop_requested
from dtmbnav_core.schema import START_UTC_NS_ATTR
from receiver.capture import STOP_POLL_S, CaptureSource, _BlockPool, _decode_block

#: URL scheme of an rtl_tcp server: ``rtl_tcp://HOST[:PORT]``.
URL_SCHEME = "rtl_tcp"
#: Bytes of one cu8 I/Q pair.
PAIR_BYTES = 2
#: Stream seconds over which the start time is refined (RtlTcpSource.start_utc_unix_ns); later bounds move only
#: the gaps' clock (a dongle's crystal runs ppm off the host's, and the start time must not follow it).
START_WINDOW_S = 1.0


class RtlTcpError(ConnectionError):
    """The rtl_tcp server cannot be reached or does not speak rtl_tcp (the message says which and where)."""


class NotRtlTcpServer(RtlTcpError):
    """Something answers at the address, but not with an rtl_tcp greeting."""


@dataclass(frozen=True)
class LinkPolicy:
    """How the source connects, waits, reconnects and fills gaps.

    Attributes
    ----------
    connect_timeout_s : float
        Longest wait for the connection and for the server's greeting, s.
    recv_timeout_s : float
        Seconds without data after which the connection counts as lost
        (``rtl_tcp`` itself gives up on a dongle after 5 s without samples).
    reconnects : int
        Reconnect tries after a loss before the stream counts as ended.
    backoff_s, max_backoff_s : float
        Wait before the second try, s, doubled for each further one up to
        ``max_backoff_s`` (the first try is at once: a server that closed
        one client is listening again within milliseconds).
    settle_s : float
        Seconds of samples dropped after the settings are sent: ``rtl_tcp``
        streams from the moment it accepts, at the dongle's old settings
        until the commands take effect (a sample-rate change resets the
        RTL2832's resampler, a retune sets the tuner's PLL over I2C).
    max_fill_s : float
        Longest run of zeros handed on for one outage, s: the receiver
        searches the zeros for a signal at several times real time, so a
        longer outage would make a live receiver fall behind; the rest is
        recorded (``outage_unfilled_samples``: the frames after such a gap
        are early on the host's clock by that many samples).
    flush_s : float
        Longest time a block waits to fill before it is handed on, s (the
        latency the source adds).
    time_scale : float
        Stream seconds per second of the host's clock: 1 for a dongle; a
        replay faster than real time (tests) gives its pace.
    """

    connect_timeout_s: float = 5.0
    recv_timeout_s: float = 3.0
    reconnects: int = 6
    backoff_s: float = 0.5
    max_backoff_s: float = 4.0
    settle_s: float = 0.5
    max_fill_s: float = 60.0
    flush_s: float = 0.1
    time_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("connect_timeout_s", "recv_timeout_s", "flush_s", "time_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"LinkPolicy.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("reconnects", "backoff_s", "max_backoff_s", "settle_s", "max_fill_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"LinkPolicy.{name} must not be negative, got {getattr(self, name)!r}")


#: The policy of a source given none.
DEFAULT_POLICY = LinkPolicy()


@dataclass(frozen=True)
class Outage:
    """One lost connection and what it cost.

    Attributes
    ----------
    sample_index : int
        Stream index of the first sample the outage lost (samples handed on before it, zeros of earlier
        outages included).
    utc_unix_ns : int
        Host UTC when the last data before it arrived, ns since the Unix epoch.
    duration_s : float
        Host seconds from the last data before it to the first data after it.
    lost_samples : int
        Samples the stream lacks there on the host's clock (:attr:`LinkPolicy.time_scale` applied).
    filled_samples : int
        Zeros handed on in their place (``lost_samples`` capped by :attr:`LinkPolicy.max_fill_s`).
    reason : str
        What ended the connection.
    """

    sample_index: int
    utc_unix_ns: int
    duration_s: float
    lost_samples: int
    filled_samples: int
    reason: str


@dataclass
class _Gap:
    """A loss waiting for the data after it: why, when the last data came (host monotonic, and UTC ns), and
    the latest time the first sample after it can have been sampled (host monotonic)."""

    reason: str
    last_data_t: float
    utc_unix_ns: int
    resumed_t: float = math.inf


class _LinkLost(Exception):
    """The connection ended; the message says how."""


def parse_url(text: str) -> tuple[str, int] | None:
    """``rtl_tcp://HOST[:PORT]`` -> (host, port); None when ``text`` is not such a URL.

    Raises
    ------
    ValueError
        An ``rtl_tcp://`` URL without a host, with a bad port, or with a path.
    """
    if not str(text).startswith(f"{URL_SCHEME}://"):
        return None
    # urlsplit takes no "_" in a scheme: the address part is split on its own.
    parts = urlsplit("//" + str(text)[len(URL_SCHEME) + 3:])
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"{text}: bad port (rtl_tcp://HOST[:PORT], port 1-65535)") from None
    if not parts.hostname or parts.path not in ("", "/") or parts.query or parts.fragment:
        raise ValueError(f"{text}: expected rtl_tcp://HOST[:PORT]")
    return parts.hostname, rtltcp.DEFAULT_PORT if port is None else port


def settings_commands(sample_rate_hz: float, center_hz: float, gain_db: float | None = None,
                      ppm: int = 0) -> list[tuple[rtltcp.Command, int]]:
    """The commands that set a dongle up, in ``rtl_tcp``'s own start-up order (frequency correction, sample
    rate, centre frequency, gain).

    ``gain_db`` None: the tuner's automatic gain; else manual gain in tenths
    of a dB (the tuner takes its nearest step).

    Raises
    ------
    ValueError
        A rate or frequency that is not a whole number of Hz within 32 bits.
    """
    out = [(rtltcp.Command.SET_FREQ_CORRECTION, int(ppm))]
    for command, value, what in ((rtltcp.Command.SET_SAMPLE_RATE, sample_rate_hz, "sample rate"),
                                 (rtltcp.Command.SET_FREQUENCY, center_hz, "centre frequency")):
        if value != round(value) or not 0 < value < 1 << 32:
            raise ValueError(f"rtl_tcp takes the {what} as a whole number of Hz below 2**32, got {value!r}")
        out.append((command, round(value)))
    if gain_db is None:
        out.append((rtltcp.Command.SET_GAIN_MODE, 0))
    else:
        out += [(rtltcp.Command.SET_GAIN_MODE, 1), (rtltcp.Command.SET_GAIN, round(gain_db * 10))]
    return out


class RtlTcpSource(CaptureSource):
    """A live cu8 stream from an ``rtl_tcp`` server (module docstring), read as a capture stream.

    Parameters
    ----------
    host : str
    port : int
    sample_rate_hz : float
        Sample rate to set, whole Hz.
    center_hz : float
        Centre frequency to set, whole Hz.
    gain_db : float or None
        Manual tuner gain, dB; None: the tuner's automatic gain.
    ppm : int
        Frequency correction to set, ppm.
    channel_hz : float or None
        Centre of the DTMB channel when tuned beside it (as for a capture).
    policy : LinkPolicy, optional
        Default :data:`DEFAULT_POLICY`.

    Attributes
    ----------
    start_utc_unix_ns : int or None
        Host UTC of the first kept sample, ns (None before it arrives): the
        arrival time of the newest sample read, less the samples before it at
        the sample rate, the earliest such time over the stream's first
        :data:`START_WINDOW_S` (then fixed). It is the host clock's (as good
        as its NTP sync), late by the least latency seen in that window, the
        network's plus the USB transfer's (``rtl_tcp`` hands on 256 KiB at a
        time: on a quiet link at most one block, 55 ms at 2.4 Msps), early by
        nothing; it moves earlier while better bounds arrive.
    greeting : dtmbnav_core.rtltcp.Greeting or None
        The server's greeting (tuner type, gain steps), once connected.
    outages : list of Outage
    end_reason : str or None
        Why the stream ended without a stop request (the server went away and
        no reconnect succeeded); None otherwise.
    """

    def __init__(self, host: str, port: int = rtltcp.DEFAULT_PORT, *, sample_rate_hz: float, center_hz: float,
                 gain_db: float | None = None, ppm: int = 0, channel_hz: float | None = None,
                 policy: LinkPolicy | None = None) -> None:
        super().__init__(path=f"{URL_SCHEME}://{host}:{port}", sample_rate_hz=float(sample_rate_hz),
                         center_hz=float(center_hz), sample_format=rtltcp.SAMPLE_FORMAT, num_samples=None,
                         channel_hz=channel_hz)
        self.host, self.port = host, int(port)
        self.gain_db, self.ppm = gain_db, int(ppm)
        self.policy = policy or DEFAULT_POLICY
        self.commands = settings_commands(self.sample_rate_hz, self.center_hz, gain_db, self.ppm)
        self.greeting: rtltcp.Greeting | None = None
        self.outages: list[Outage] = []
        self.end_reason: str | None = None
        self.handed_samples = 0            # samples yielded so far, zeros included
        self._sock: socket.socket | None = None
        #: Host monotonic time of the stream's first sample: the earliest bound the arrivals give (_stream).
        self._start_t = math.inf
        self._utc_offset_ns: int | None = None
        self._streamed = False

    @property
    def is_stream(self) -> bool:
        """Always: a live stream cannot be read twice and has no length."""
        return True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection (a later :meth:`chunks` cannot reopen it)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def open(self) -> rtltcp.Greeting:
        """Connect, read the greeting and send the settings; called by :meth:`chunks` when not yet done.

        Raises
        ------
        RtlTcpError
            Connection refused or timed out, host unknown (the message names
            host:port and says that rtl_tcp must be running there).
        NotRtlTcpServer
            The server's first bytes are not an rtl_tcp greeting.
        """
        if self._sock is None:
            self._connect()
        assert self.greeting is not None
        return self.greeting

    def _connect(self) -> None:
        where = f"{self.host}:{self.port}"
        timeout = self.policy.connect_timeout_s
        try:
            sock = socket.create_connection((self.host, self.port), timeout=timeout)
        except ConnectionRefusedError:
            raise RtlTcpError(f"{self.path}: connection refused: nothing listens on {where}; rtl_tcp must be "
                              f"running there (e.g. rtl_tcp -a <its address> -p {self.port})") from None
        except socket.gaierror as exc:
            raise RtlTcpError(f"{self.path}: unknown host {self.host!r} ({exc.strerror})") from None
        except TimeoutError:
            raise RtlTcpError(f"{self.path}: no answer from {where} within {timeout:g} s; is rtl_tcp running "
                              "there and reachable?") from None
        except OSError as exc:
            raise RtlTcpError(f"{self.path}: cannot connect to {where}: {exc.strerror or exc}; rtl_tcp must be "
                              "running there") from None
        try:
            greeting = self._read_greeting(sock, timeout)
            sock.sendall(b"".join(rtltcp.encode_command(c, v) for c, v in self.commands))
            self._settle(sock)
        except BaseException:
            sock.close()
            raise
        self._sock, self.greeting = sock, greeting

    def _read_greeting(self, sock: socket.socket, timeout: float) -> rtltcp.Greeting:
        """The server's 12 bytes, read while honouring a stop request; the connection's own errors as RtlTcpError."""
        sock.settimeout(STOP_POLL_S)
        data = b""
        deadline = time.monotonic() + timeout
        while len(data) < rtltcp.GREETING.size:
            try:
                part = sock.recv(rtltcp.GREETING.size - len(data))
            except TimeoutError:
                if time.monotonic() > deadline or stop_requested():
                    raise NotRtlTcpServer(f"{self.path}: the server at {self.host}:{self.port} sent no rtl_tcp "
                                          f"greeting within {timeout:g} s: not an rtl_tcp server?") from None
                continue
            except OSError as exc:
                raise RtlTcpError(f"{self.path}: connection lost before the greeting: {exc.strerror or exc}") from None
            if not part:
                raise NotRtlTcpServer(f"{self.path}: the server at {self.host}:{self.port} closed the connection "
                                      f"after {len(data)} byte(s), without an rtl_tcp greeting: not an rtl_tcp "
                                      "server (or it serves another client)")
            data += part
        try:
            return rtltcp.Greeting.decode(data)
        except rtltcp.NotRtlTcp as exc:
            raise NotRtlTcpServer(f"{self.path}: not an rtl_tcp server ({exc})") from None

    def _settle(self, sock: socket.socket) -> None:
        """Drop what arrives for :attr:`LinkPolicy.settle_s` (samples at the dongle's previous settings)."""
        end = time.monotonic() + self.policy.settle_s
        scratch = bytearray(1 << 16)
        while (left := end - time.monotonic()) > 0 and not stop_requested():
            sock.settimeout(min(left, STOP_POLL_S))
            try:
                if not sock.recv_into(scratch):
                    raise RtlTcpError(f"{self.path}: the server closed the connection after the settings")
            except TimeoutError:
                continue

    def _recv_some(self, view: memoryview) -> int:
        """Read into ``view`` what has arrived, waiting for at least one byte; 0 on a stop request.

        Raises
        ------
        _LinkLost
            The server closed the connection, an error, or no data for
            :attr:`LinkPolicy.recv_timeout_s`.
        """
        assert self._sock is not None
        deadline = time.monotonic() + self.policy.recv_timeout_s
        while True:
            try:
                count = self._sock.recv_into(view)
            except TimeoutError:
                if stop_requested():
                    return 0
                if time.monotonic() > deadline:
                    raise _LinkLost(f"no data for {self.policy.recv_timeout_s:g} s") from None
                continue
            except OSError as exc:
                raise _LinkLost(exc.strerror or type(exc).__name__) from None
            if not count:
                raise _LinkLost("the server closed the connection")
            return count

    def chunks(self, chunk_samples: int) -> Iterator[np.ndarray]:
        """Yield the stream as complex64 arrays of at most ``chunk_samples``, zeros in the gaps; once only.

        A block is handed on when full or :attr:`LinkPolicy.flush_s` after
        its first byte arrived. The arrays come from a pool and are reused
        once nothing else refers to them (as the capture reader's).

        Raises
        ------
        RtlTcpError
            The first connection failed (:meth:`open`); later losses are gaps.
        ValueError
            ``chunk_samples`` not positive, or a second call.
        """
        if chunk_samples <= 0:
            raise ValueError(f"chunk_samples must be positive, got {chunk_samples}")
        if self._streamed:
            raise ValueError(f"{self.path}: a live stream can be read once")
        self._streamed = True
        self.open()
        assert self._sock is not None
        self._sock.settimeout(STOP_POLL_S)
        return self._stream(chunk_samples)

    def _stream(self, chunk_samples: int) -> Iterator[np.ndarray]:
        fmt = self.format
        blocks = _BlockPool(chunk_samples)
        buffer = bytearray(chunk_samples * PAIR_BYTES)
        raw = np.frombuffer(buffer, np.uint8)
        view = memoryview(buffer)
        zeros = np.zeros(chunk_samples, np.complex64)
        zeros.flags.writeable = False   # shared by every gap's blocks: nobody may write into it
        rate = self.sample_rate_hz * self.policy.time_scale   # stream samples per host second
        filled = 0               # bytes in the buffer
        block_t = 0.0            # when the buffer's first byte arrived
        last_data_t = 0.0        # when the last data arrived (host monotonic)
        gap: _Gap | None = None  # a loss whose zeros wait for the data after it

        def hand_on(size: int) -> Iterator[np.ndarray]:
            """The buffer's first ``size`` bytes, after the zeros of a gap before them."""
            nonlocal gap
            if gap is not None:
                yield from self._fill(gap, zeros)
                gap = None
            yield self._decoded(raw, size, fmt, blocks)

        try:
            while not stop_requested():
                try:
                    count = self._recv_some(view[filled:])
                except _LinkLost as exc:
                    if filled >= PAIR_BYTES:
                        yield from hand_on(filled - filled % PAIR_BYTES)
                    filled = 0   # an odd byte's partner was lost with the connection
                    if gap is None and self.handed_samples:   # nothing before it: no gap in the stream
                        gap = _Gap(str(exc), last_data_t, self._utc_ns(last_data_t))
                    if not self._reconnect(str(exc)):
                        gap = None   # nothing comes after it
                        break
                    continue
                if count == 0:   # a stop request
                    break
                now = time.monotonic()
                if filled == 0:
                    block_t = now
                filled += count
                last_data_t = now
                # The newest sample read arrived now, so the buffer's first one was sampled no later than this
                # (host clock): the earliest such bound is the one with the least network and USB latency.
                first_at = now - (filled // PAIR_BYTES) / rate
                if gap is not None:   # the buffer starts with the first sample after the gap
                    gap.resumed_t = min(gap.resumed_t, first_at)
                elif first_at - self.handed_samples / rate < self._start_t:
                    self._start_t = first_at - self.handed_samples / rate
                    if self.handed_samples < START_WINDOW_S * self.sample_rate_hz:
                        self.start_utc_unix_ns = self._utc_ns(self._start_t)
                if filled == len(buffer) or now - block_t >= self.policy.flush_s:
                    whole = filled - filled % PAIR_BYTES
                    yield from hand_on(whole)
                    buffer[:filled - whole] = buffer[whole:filled]
                    filled -= whole
                    block_t = now
            if filled >= PAIR_BYTES:   # a stop: what was read is handed on
                yield from hand_on(filled - filled % PAIR_BYTES)
        finally:
            self.close()

    def _utc_ns(self, monotonic_t: float) -> int:
        """Host UTC, ns, of a host monotonic time (one offset for the whole stream, so that a step of the
        wall clock does not move the samples)."""
        if self._utc_offset_ns is None:
            self._utc_offset_ns = time.time_ns() - time.monotonic_ns()
        return self._utc_offset_ns + round(monotonic_t * 1e9)

    def _decoded(self, raw: np.ndarray, size: int, fmt: Any, blocks: _BlockPool) -> np.ndarray:
        samples = _decode_block(raw[:size], fmt, blocks, where=f"{self.path} (from sample {self.handed_samples})")
        self.handed_samples += len(samples)
        return samples

    def _reconnect(self, reason: str) -> bool:
        """Connect again after a loss; False when every try failed (the stream's end) or a stop was requested."""
        self.close()
        failure = ""
        for attempt in range(self.policy.reconnects):
            wait = 0.0 if attempt == 0 else min(self.policy.backoff_s * 2 ** (attempt - 1), self.policy.max_backoff_s)
            if not _sleep(wait):
                return False
            try:
                self._connect()
            except RtlTcpError as exc:
                failure = str(exc)
                continue
            assert self._sock is not None
            self._sock.settimeout(STOP_POLL_S)
            return True
        if not stop_requested():
            self.end_reason = (f"the connection was lost after sample {self.handed_samples} ({reason}) and "
                               f"{self.policy.reconnects} reconnect(s) failed" + (f" (last: {failure})" if failure else ""))
        return False

    def _fill(self, gap: _Gap, zeros: np.ndarray) -> Iterator[np.ndarray]:
        """Record an outage and yield its zeros: up to the stream index the host's clock gives the first sample
        after it."""
        rate = self.sample_rate_hz * self.policy.time_scale
        missing = max(round((gap.resumed_t - self._start_t) * rate) - self.handed_samples, 0)
        fill = min(missing, round(self.policy.max_fill_s * self.sample_rate_hz))
        self.outages.append(Outage(self.handed_samples, gap.utc_unix_ns, gap.resumed_t - gap.last_data_t, missing,
                                   fill, gap.reason))
        self.handed_samples += fill
        for start in range(0, fill, len(zeros)):
            yield zeros[:min(len(zeros), fill - start)]

    def attributes(self) -> Mapping[str, Any]:
        """The ``/receiver/frames`` attributes this source adds, read when iterated (at the end of a run).

        ``rtl_tcp_*``: the server's tuner, the settings sent, and
        ``rtl_tcp_end`` (why the stream ended, when the server went away);
        ``outages`` and one array per :class:`Outage` field (``outage_*``);
        and the capture start time (``start_utc_unix_ns``) once known.
        """
        return _LiveAttributes(self)

    def current_attributes(self) -> dict[str, Any]:
        """:meth:`attributes` as they are now."""
        out: dict[str, Any] = {
            "rtl_tcp_server": f"{self.host}:{self.port}",
            "rtl_tcp_tuner": self.greeting.tuner_name if self.greeting else "unknown",
            "rtl_tcp_gain_db": np.nan if self.gain_db is None else float(self.gain_db),
            "rtl_tcp_ppm": self.ppm,
            "outages": len(self.outages),
            "outage_sample_index": np.array([o.sample_index for o in self.outages], np.int64),
            "outage_t_s": np.array([o.sample_index / self.sample_rate_hz for o in self.outages], np.float64),
            "outage_utc_unix_ns": np.array([o.utc_unix_ns for o in self.outages], np.int64),
            "outage_duration_s": np.array([o.duration_s for o in self.outages], np.float64),
            "outage_lost_samples": np.array([o.lost_samples for o in self.outages], np.int64),
            "outage_unfilled_samples": np.array([o.lost_samples - o.filled_samples for o in self.outages], np.int64),
        }
        if self.end_reason is not None:
            out["rtl_tcp_end"] = self.end_reason
        if self.start_utc_unix_ns is not None:
            out[START_UTC_NS_ATTR] = np.int64(self.start_utc_unix_ns)
        return out


class _LiveAttributes(Mapping[str, Any]):
    """:meth:`RtlTcpSource.attributes`: a mapping whose values are taken when it is read."""

    def __init__(self, source: RtlTcpSource) -> None:
        self._source = source

    def __getitem__(self, key: str) -> Any:
        return self._source.current_attributes()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._source.current_attributes())

    def __len__(self) -> int:
        return len(self._source.current_attributes())


def _sleep(seconds: float) -> bool:
    """Sleep, waking for a stop request; False when one came."""
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        if stop_requested():
            return False
        time.sleep(min(left, STOP_POLL_S))
    return not stop_requested()

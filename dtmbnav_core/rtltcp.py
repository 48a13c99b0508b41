"""The byte layout of osmocom rtl-sdr's ``rtl_tcp`` protocol (``src/rtl_tcp.c``), for its client and its replay.

- **Greeting**: right after accepting a client the server sends 12 bytes,
  the magic ``b"RTL0"``, the tuner type and the tuner's number of gain steps
  (each a big-endian uint32; ``dongle_info_t``).
- **Commands**: the client sends 5 bytes each, a command id (uint8) and its
  parameter (big-endian uint32; ``struct command``). The server passes the
  parameter to librtlsdr as an int, so a signed value (the frequency
  correction in ppm) travels as its 32-bit two's complement.
- **Samples**: after the greeting the server streams interleaved unsigned
  8-bit I/Q (``cu8``) until the connection ends; it starts with whatever the
  dongle was set to, so samples sent before a command took effect are at the
  old settings.

The client (:mod:`receiver.rtl_tcp`) and the simulator's replay server
(:mod:`sim.rtl_tcp_replay`) share this module so that both speak the same
bytes.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

#: The server's port when none is given (``rtl_tcp -p``'s default).
DEFAULT_PORT = 1234
#: The first four bytes of the greeting.
MAGIC = b"RTL0"
#: Sample format of the stream (``dtmbnav_core.iqformat`` name).
SAMPLE_FORMAT = "cu8"
GREETING = struct.Struct(">4sII")
COMMAND = struct.Struct(">BI")


class Command(enum.IntEnum):
    """Command ids of ``rtl_tcp.c``'s ``command_worker``, with the parameter each takes."""

    SET_FREQUENCY = 0x01          #: centre frequency, Hz
    SET_SAMPLE_RATE = 0x02        #: samples/s
    SET_GAIN_MODE = 0x03          #: 0: the tuner's automatic gain, 1: manual gain
    SET_GAIN = 0x04               #: tuner gain, tenths of a dB (manual mode; the tuner takes its nearest step)
    SET_FREQ_CORRECTION = 0x05    #: frequency correction, ppm (signed)
    SET_IF_GAIN = 0x06            #: IF stage << 16 | gain in tenths of a dB
    SET_TEST_MODE = 0x07          #: 0/1
    SET_AGC_MODE = 0x08           #: the RTL2832's digital AGC, 0/1
    SET_DIRECT_SAMPLING = 0x09    #: 0 off, 1 I branch, 2 Q branch
    SET_OFFSET_TUNING = 0x0A      #: 0/1
    SET_RTL_XTAL = 0x0B           #: RTL2832 crystal, Hz
    SET_TUNER_XTAL = 0x0C         #: tuner crystal, Hz
    SET_GAIN_BY_INDEX = 0x0D      #: index into the tuner's gain table
    SET_BIAS_TEE = 0x0E           #: 0/1


#: Commands whose parameter librtlsdr reads as a signed int.
SIGNED_COMMANDS = frozenset({Command.SET_FREQ_CORRECTION})

#: Tuner types of librtlsdr's ``enum rtlsdr_tuner``, by the number the greeting carries.
TUNER_NAMES = ("unknown", "E4000", "FC0012", "FC0013", "FC2580", "R820T", "R828D")


class NotRtlTcp(ValueError):
    """The server's first bytes are not an rtl_tcp greeting."""


@dataclass(frozen=True)
class Greeting:
    """The server's 12-byte greeting.

    Attributes
    ----------
    tuner_type : int
        librtlsdr's tuner type (:data:`TUNER_NAMES`).
    gain_count : int
        Gain steps of the tuner.
    """

    tuner_type: int
    gain_count: int

    @property
    def tuner_name(self) -> str:
        """The tuner's name (``"R820T"``, ...), or ``"type N"`` for a number librtlsdr does not list."""
        known = 0 <= self.tuner_type < len(TUNER_NAMES)
        return TUNER_NAMES[self.tuner_type] if known else f"type {self.tuner_type}"

    def encode(self) -> bytes:
        """The 12 bytes a server sends."""
        return GREETING.pack(MAGIC, self.tuner_type, self.gain_count)

    @classmethod
    def decode(cls, data: bytes) -> Greeting:
        """Read a greeting.

        Raises
        ------
        NotRtlTcp
            Not 12 bytes, or not starting with ``RTL0``.
        """
        if len(data) != GREETING.size:
            raise NotRtlTcp(f"the greeting is {GREETING.size} bytes, got {len(data)}")
        magic, tuner_type, gain_count = GREETING.unpack(data)
        if magic != MAGIC:
            raise NotRtlTcp(f"the greeting starts with {magic!r}, not {MAGIC!r}")
        return cls(tuner_type, gain_count)


def encode_command(command: Command, value: int) -> bytes:
    """The 5 bytes of one command; ``value`` in -2**31 .. 2**32 - 1 (a negative one as two's complement).

    Raises
    ------
    ValueError
        ``value`` does not fit 32 bits.
    """
    value = int(value)
    if not -(1 << 31) <= value < (1 << 32):
        raise ValueError(f"rtl_tcp {Command(command).name}: {value} does not fit 32 bits")
    return COMMAND.pack(int(command), value & 0xFFFFFFFF)


def decode_command(data: bytes) -> tuple[Command | int, int]:
    """One 5-byte command as (command, value): a known id as :class:`Command`, a signed command's value signed."""
    code, raw = COMMAND.unpack(data)
    try:
        command: Command | int = Command(code)
    except ValueError:
        return code, raw
    if command in SIGNED_COMMANDS and raw >= 1 << 31:
        return command, raw - (1 << 32)
    return command, raw

"""Interleaved IQ sample formats shared by the capture writer and reader.

Four formats (``docs/conventions.md``): ``cu8`` (unsigned bytes, offset 128),
``ci8`` (signed bytes), ``ci16`` (little-endian int16) and ``cf32``
(little-endian float32), each an interleaved I, Q pair per sample. Decoding
normalises to complex64 with full scale at +-1: cu8 ``(v - 127.4) / 128``, ci8
``v / 128``, ci16 ``v / 32768``, cf32 as is. The cu8 centre is the RTL-SDR
drivers' (gr-osmosdr's ``rtl_source_c`` and SoapyRTLSDR convert with
``(v - 127.4) / 128``: an RTL2832U's bytes centre there, not at 128;
``docs/devices.md``); whatever DC a device leaves, the receiver measures and
removes. Encoding is the inverse of a quantiser centred on the format's
midpoint (128 for cu8), with rounding to the nearest level and clipping to the
format's range; a simulated device's own centre is its ADC DC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class IqFormat:
    """One interleaved IQ sample format.

    Attributes
    ----------
    name : str
        Project name (``cu8``, ``ci8``, ``ci16``, ``cf32``).
    sigmf_datatype : str
        SigMF ``core:datatype`` string.
    dtype : numpy.dtype
        Storage type of one rail (I or Q).
    scale : float
        Integer value of full scale (1.0 after decoding); 1 for cf32.
    offset : float
        Integer value of zero when encoding (128 for cu8).
    decode_offset : float
        Value subtracted when decoding: the drivers' zero (127.4 for cu8).
    """

    name: str
    sigmf_datatype: str
    dtype: np.dtype
    scale: float
    offset: float
    decode_offset: float

    @property
    def bytes_per_sample(self) -> int:
        """Bytes of one complex sample (I and Q)."""
        return 2 * self.dtype.itemsize

    @property
    def is_integer(self) -> bool:
        """True for the quantised formats (rounding and clipping apply)."""
        return self.dtype.kind in "iu"


FORMATS: dict[str, IqFormat] = {
    "cu8": IqFormat("cu8", "cu8", np.dtype(np.uint8), 128.0, 128.0, 127.4),
    "ci8": IqFormat("ci8", "ci8", np.dtype(np.int8), 128.0, 0.0, 0.0),
    "ci16": IqFormat("ci16", "ci16_le", np.dtype("<i2"), 32768.0, 0.0, 0.0),
    "cf32": IqFormat("cf32", "cf32_le", np.dtype("<f4"), 1.0, 0.0, 0.0),
}

_BY_SIGMF = {fmt.sigmf_datatype: fmt for fmt in FORMATS.values()}


def get_format(name: str) -> IqFormat:
    """The format called ``name`` (project name, e.g. ``"ci16"``).

    Raises
    ------
    ValueError
        For an unknown name; the message lists the known ones.
    """
    try:
        return FORMATS[str(name).lower()]
    except KeyError:
        raise ValueError(f"unknown IQ sample format {name!r}; expected one of {', '.join(FORMATS)}") from None


def from_sigmf_datatype(datatype: str) -> IqFormat:
    """The format of a SigMF ``core:datatype`` (``cu8``, ``ci8``, ``ci16_le``, ``cf32_le``).

    Raises
    ------
    ValueError
        For a datatype the project does not read (real-valued, big-endian, other widths).
    """
    try:
        return _BY_SIGMF[datatype]
    except KeyError:
        raise ValueError(f"unsupported SigMF datatype {datatype!r}; expected one of {', '.join(_BY_SIGMF)}") from None


def decode(data: bytes | bytearray | memoryview | np.ndarray, fmt: str | IqFormat, *,
           where: str = "IQ data", out: np.ndarray | None = None) -> np.ndarray:
    """Decode interleaved IQ bytes (or a rail array of the format's dtype) to complex64.

    Parameters
    ----------
    data : bytes-like or ndarray
        Raw bytes, or an array of rails (I, Q, I, Q, ...) of the storage dtype.
    fmt : str or IqFormat
        Sample format.
    where : str
        Name used in error messages (a file name).
    out : ndarray of complex64, optional
        Where to write the samples (one per IQ pair): a reader that reuses
        one buffer converts in a single pass, without temporaries.

    Returns
    -------
    numpy.ndarray of complex64
        Samples normalised to full scale +-1 (``out`` when given).

    Raises
    ------
    ValueError
        A byte count that is not a whole number of IQ pairs, or NaN/inf in cf32.
    """
    fmt = fmt if isinstance(fmt, IqFormat) else get_format(fmt)
    if isinstance(data, np.ndarray) and data.dtype != np.uint8:
        rails = np.ascontiguousarray(data, dtype=fmt.dtype)
    else:
        raw = memoryview(data).cast("B") if not isinstance(data, np.ndarray) else data
        nbytes = len(raw)
        if nbytes % fmt.bytes_per_sample:
            raise ValueError(f"{where}: {nbytes} bytes is not a whole number of {fmt.name} IQ pairs "
                             f"({fmt.bytes_per_sample} bytes each): truncated data (half an IQ pair)")
        rails = np.frombuffer(raw, dtype=fmt.dtype)
    if len(rails) % 2:
        raise ValueError(f"{where}: odd number of rails ({len(rails)}): half an IQ pair")
    if out is None:
        out = np.empty(len(rails) // 2, dtype=np.complex64)
    elif out.dtype != np.complex64 or out.shape != (len(rails) // 2,):
        raise ValueError(f"{where}: out must be complex64 of shape ({len(rails) // 2},), got {out.dtype} {out.shape}")
    values = out.view(np.float32)
    if fmt.is_integer:
        # The full scales are powers of two, so multiplying by the reciprocal is exact (= dividing).
        if fmt.decode_offset:
            np.subtract(rails, np.float32(fmt.decode_offset), out=values)
            np.multiply(values, np.float32(1.0 / fmt.scale), out=values)
        else:
            np.multiply(rails, np.float32(1.0 / fmt.scale), out=values)
    else:
        values[:] = rails
        finite = np.isfinite(values)
        if not finite.all():
            first = int(np.argmin(finite)) // 2
            raise ValueError(f"{where}: NaN or inf in cf32 data (sample {first} of this block)")
    return out


def interleave(samples: np.ndarray, fmt: IqFormat) -> np.ndarray:
    """Complex samples as float64 rails (I, Q, I, Q, ...), checked finite, for an encoder of ``fmt``.

    Raises
    ------
    ValueError
        NaN or inf in the input (the message names the format).
    """
    z = np.asarray(samples)
    rails = np.empty(2 * z.size, dtype=np.float64)
    rails[0::2] = z.real.ravel()
    rails[1::2] = z.imag.ravel()
    if not np.isfinite(rails).all():
        raise ValueError(f"cannot encode NaN or inf samples to {fmt.name}")
    return rails


def encode(samples: np.ndarray, fmt: str | IqFormat) -> np.ndarray:
    """Encode complex samples (full scale +-1) to the interleaved rails of a format.

    Integer formats round to the nearest level and clip to the format's range
    (cu8 0..255, ci8 -128..127, ci16 -32768..32767); cf32 stores float32.

    Returns
    -------
    numpy.ndarray
        Rails (I, Q, I, Q, ...) of the format's storage dtype; ``.tobytes()``
        gives the file bytes.

    Raises
    ------
    ValueError
        NaN or inf in the input.
    """
    fmt = fmt if isinstance(fmt, IqFormat) else get_format(fmt)
    rails = interleave(samples, fmt)
    if not fmt.is_integer:
        return rails.astype(fmt.dtype)
    info = np.iinfo(fmt.dtype)
    levels = np.rint(rails * fmt.scale + fmt.offset)
    return np.clip(levels, info.min, info.max).astype(fmt.dtype)

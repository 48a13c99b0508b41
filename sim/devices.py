"""SDR device presets: the ``[receiver]`` keys that describe the receivers people record DTMB with.

A preset is the set of :class:`sim.scenario.FrontEndConfig` fields that a
device fixes at the rate and sample format it is usually run at for DTMB:
rate, format, ADC resolution and DC, reference oscillator, LO leakage, IQ
imbalance, phase noise, AGC steps and USB sample drops.
:func:`apply_device` writes them into a scenario; the keys a device does not
fix (``cn_db``, ``agc_backoff_db``, ``start_offset_s``, ``bulk_cfo_hz``,
``iq_conjugate``) keep the scenario's values. Every preset sets every one of
its keys, so applying one replaces whatever impairments the scenario had.

Every value of every preset has its row in the figure table of
``docs/devices.md``: the datasheet, driver source file or published
measurement it comes from, or the assumption it is and why, and the range
the front-end sweep covers around it.

The clock is always ``preset = "custom"`` with a fixed, representative
``offset_ppb`` (a unit inside the oscillator's stated tolerance, not a draw
from it: :func:`sim.oscillator.clock_parameters` draws only for the named
presets) and the ``drift_adev`` of its oscillator class.

Zero-IF devices (HackRF One, PlutoSDR, USRP B200) put their LO leakage at
DC, where the SI carriers of the channel sit; their users tune beside the
channel. The presets keep ``tuning_offset_hz`` at 0 (the channel on the
capture's centre, the harder case) and :attr:`DevicePreset.practice` says
what offset a recording would use.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from sim.scenario import Scenario

#: Phase-noise profile ``[[offset_hz, dBc/Hz], ...]`` of an AD936x RX LO at UHF (docs/devices.md, figure table).
AD936X_PHASE_NOISE = ((1e3, -95.0), (1e4, -103.0), (1e5, -106.0), (1e6, -128.0))
#: Phase-noise profile of the R820T/R820T2 tuner at UHF (docs/devices.md: an assumption).
R820T_PHASE_NOISE = ((1e3, -80.0), (1e4, -88.0), (1e5, -95.0), (1e6, -115.0))
#: Phase-noise profile of the HackRF One at UHF (docs/devices.md, figure table).
HACKRF_PHASE_NOISE = ((1e3, -85.0), (1e4, -92.0), (1e5, -93.0), (1e6, -115.0))

#: Allan deviation at 1 s of a TCXO: the project's free-running clock preset (docs/devices.md).
TCXO_ADEV = 1e-9
#: Allan deviation at 1 s of a plain crystal oscillator (docs/devices.md: a warm-up drift read as a random walk).
XO_ADEV = 1e-8


@dataclass(frozen=True)
class DevicePreset:
    """One SDR at its usual DTMB rate and format.

    Attributes
    ----------
    name : str
        Preset name (``"rtl-sdr"``, ``"hackrf-one"``, ...).
    description : str
        The hardware it describes, in a line.
    receiver : Mapping
        ``[receiver]`` keys and values; ``clock`` is a table
        ``{"preset": "custom", "offset_ppb": ..., "drift_adev": ...}``.
    practice : str
        How people record with it, where that differs from the preset
        (off-centre tuning, gain settings).
    """

    name: str
    description: str
    receiver: Mapping[str, Any]
    practice: str = ""

    def receiver_table(self) -> dict[str, Any]:
        """A fresh, mutable copy of :attr:`receiver`: lists as lists, the clock as a dict (TOML's shapes)."""
        return {key: _thaw(value) for key, value in self.receiver.items()}


def _freeze(value: Any) -> Any:
    """Lists as tuples and dicts as read-only mappings, so that a preset cannot be changed in place."""
    if isinstance(value, dict):
        return MappingProxyType({key: _freeze(item) for key, item in value.items()})
    if isinstance(value, list):
        return tuple(_freeze(item) for item in value)
    return value


def _thaw(value: Any) -> Any:
    """The inverse of :func:`_freeze`: fresh lists and dicts."""
    if isinstance(value, Mapping):
        return {key: _thaw(item) for key, item in value.items()}
    if isinstance(value, tuple):
        return [_thaw(item) for item in value]
    return value


def _profile(points: tuple[tuple[float, float], ...]) -> list[list[float]]:
    return [[float(f), float(level)] for f, level in points]


def _preset(name: str, description: str, receiver: dict[str, Any], practice: str = "") -> DevicePreset:
    return DevicePreset(name, description, _freeze(receiver), practice)


def _rtl_sdr(name: str, description: str, offset_ppb: float, drift_adev: float) -> DevicePreset:
    """An RTL2832U + R820T/R820T2 (or R828D) dongle; the variants differ only in their oscillator."""
    # Sources and assumptions: docs/devices.md, figure table, rows rtl-sdr and rtl-sdr-generic.
    receiver = {
        # The widest rate known to run without drops: it records only the centre of the channel, which still
        # holds the SI carriers.
        "sample_rate_hz": 2.4e6,
        "sample_format": "cu8",
        "adc_bits": 8,
        # The bytes centre on 127.4 (the constant the maintained drivers subtract), not 128.
        "adc_dc_lsb": [-0.6, -0.6],
        "clock": {"preset": "custom", "offset_ppb": offset_ppb, "drift_adev": drift_adev},
        # Low-IF tuner and digital downconversion in the RTL2832U: the tuner's LO lies outside the recorded band,
        # and I and Q come from one ADC, so they are balanced.
        "tuning_offset_hz": 0.0,
        "lo_leakage_dbc": None,
        "lo_leakage_phase_deg": 0.0,
        "iq_gain_db": 0.0,
        "iq_phase_deg": 0.0,
        "phase_noise_dbc_hz": _profile(R820T_PHASE_NOISE),
        # rtl_sdr without -g runs the tuner's AGC.
        "agc_step_db": 2.0,
        "agc_steps_per_minute": 1.0,
        "drops_per_minute": 0.0,
        # A drop loses whole librtlsdr buffers.
        "drop_samples": [131072, 524288],
    }
    practice = ("2.4 Msps is the rate that runs without drops (3.2 Msps is the maximum); it cannot cover the "
                "7.56 MHz channel. No off-centre tuning: the low-IF tuner has no LO spike at DC, and the RTL2832U's "
                "byte offset is the adc_dc_lsb. A fixed gain (rtl_sdr -g) removes the AGC steps.")
    return _preset(name, description, receiver, practice)


def _ad936x(name: str, description: str, rate_hz: float, offset_ppb: float, drift_adev: float,
            agc_step_db: float, agc_steps_per_minute: float, drops_per_minute: float,
            drop_samples: list[int], practice: str) -> DevicePreset:
    """A zero-IF AD9361/AD9363 front end with its RF DC and quadrature tracking on (the drivers' default)."""
    receiver = {
        "sample_rate_hz": rate_hz,
        "sample_format": "ci16",
        "adc_bits": 12,
        "adc_dc_lsb": [0.0, 0.0],
        "clock": {"preset": "custom", "offset_ppb": offset_ppb, "drift_adev": drift_adev},
        "tuning_offset_hz": 0.0,
        # What the DC tracking leaves of the LO leakage.
        "lo_leakage_dbc": -60.0,
        "lo_leakage_phase_deg": 0.0,
        # What the quadrature tracking leaves.
        "iq_gain_db": 0.02,
        "iq_phase_deg": 0.2,
        "phase_noise_dbc_hz": _profile(AD936X_PHASE_NOISE),
        "agc_step_db": agc_step_db,
        "agc_steps_per_minute": agc_steps_per_minute,
        "drops_per_minute": drops_per_minute,
        "drop_samples": drop_samples,
    }
    return _preset(name, description, receiver, practice)


def _devices() -> dict[str, DevicePreset]:
    rtl = _rtl_sdr("rtl-sdr", "RTL2832U + R820T2/R828D with a 1 ppm TCXO (RTL-SDR Blog V3, V4)",
                   offset_ppb=500.0, drift_adev=TCXO_ADEV)
    generic = _rtl_sdr("rtl-sdr-generic",
                       "RTL2832U + R820T/R820T2 with a plain 28.8 MHz crystal (generic DVB-T dongle)",
                       offset_ppb=40_000.0, drift_adev=XO_ADEV)
    # Sources and assumptions: docs/devices.md, figure table, rows hackrf-one.
    hackrf = _preset(
        "hackrf-one", "HackRF One: RFFC5072 mixer, MAX2837 zero-IF transceiver, MAX5864 8-bit ADC, 25 MHz crystal",
        {
            # hackrf_transfer's default rate.
            "sample_rate_hz": 10e6,
            "sample_format": "ci8",
            "adc_bits": 8,
            # The DC is modelled whole as the LO leakage.
            "adc_dc_lsb": [0.0, 0.0],
            "clock": {"preset": "custom", "offset_ppb": 10_000.0, "drift_adev": XO_ADEV},
            "tuning_offset_hz": 0.0,
            # Nothing in the RX path removes the DC spike.
            "lo_leakage_dbc": -20.0,
            "lo_leakage_phase_deg": 0.0,
            # No quadrature calibration in the MAX2837 path.
            "iq_gain_db": 0.5,
            "iq_phase_deg": 3.0,
            "phase_noise_dbc_hz": _profile(HACKRF_PHASE_NOISE),
            # hackrf_transfer runs fixed LNA and VGA gains.
            "agc_step_db": 0.0,
            "agc_steps_per_minute": 0.0,
            "drops_per_minute": 0.2,
            # A drop loses whole libhackrf transfers.
            "drop_samples": [131072, 524288],
        },
        "GSG's docs recommend off-centre tuning to keep the DC spike out of the signal: at 10 Msps "
        "tuning_offset_hz = 1e6 moves the SI carriers 1 MHz from DC and keeps nearly all the channel in band; "
        "20 Msps holds the whole channel beside the spike.")
    # Sources and assumptions: docs/devices.md, figure table, rows plutosdr.
    pluto = _ad936x(
        "plutosdr", "ADALM-PLUTO: AD9363 zero-IF transceiver, 12-bit ADC, 40 MHz crystal oscillator, USB 2.0",
        rate_hz=8e6, offset_ppb=12_000.0, drift_adev=XO_ADEV,
        agc_step_db=2.0, agc_steps_per_minute=4.0, drops_per_minute=1.0, drop_samples=[65536, 262144],
        practice="8 Msps of 16-bit IQ (32 MB/s) is near what USB 2.0 carries, so some runs drop samples. The "
                 "driver's default gain mode is the slow-attack AGC; gain_control_mode 'manual' removes the steps. "
                 "libiio and SoapySDR deliver the 12 bits right-aligned (full scale 2048). Tuning a few hundred kHz "
                 "beside the channel keeps the SI carriers out of the DC tracking's notch.")
    # Sources and assumptions: docs/devices.md, figure table, rows usrp-b200.
    b200 = _ad936x(
        "usrp-b200", "Ettus USRP B200/B210: AD9361 zero-IF transceiver, 12-bit ADC, 40 MHz TCXO, USB 3.0",
        rate_hz=10e6, offset_ppb=1_000.0, drift_adev=TCXO_ADEV,
        agc_step_db=0.0, agc_steps_per_minute=0.0, drops_per_minute=0.0, drop_samples=[2040, 65280],
        practice="UHD keeps the AD9361's AGC off and its DC-offset and IQ-balance tracking on. A tune request with "
                 "lo_offset moves the LO beside the channel inside the device and the FPGA shifts the channel back "
                 "to the capture's centre, so the recording looks centred and the leakage sits at -lo_offset (the "
                 "simulator's tuning_offset_hz models the other practice, a capture centred beside the channel).")
    # Sources and assumptions: docs/devices.md, figure table, rows airspy-r2.
    airspy = _preset(
        "airspy-r2", "Airspy R2: R820T2 low-IF tuner, 12-bit ADC at 20 Msps real, 0.5 ppm TCXO; libairspy makes IQ",
        {
            "sample_rate_hz": 10e6,
            "sample_format": "ci16",
            "adc_bits": 12,
            # libairspy's DC blocker removes the ADC's offset before the real-to-IQ conversion.
            "adc_dc_lsb": [0.0, 0.0],
            "clock": {"preset": "custom", "offset_ppb": 250.0, "drift_adev": TCXO_ADEV},
            "tuning_offset_hz": 0.0,
            # Low IF and a host-side fs/4 translation: no LO at DC, I and Q balanced by construction.
            "lo_leakage_dbc": None,
            "lo_leakage_phase_deg": 0.0,
            "iq_gain_db": 0.0,
            "iq_phase_deg": 0.0,
            "phase_noise_dbc_hz": _profile(R820T_PHASE_NOISE),
            # airspy_rx runs fixed LNA, mixer and VGA gains.
            "agc_step_db": 0.0,
            "agc_steps_per_minute": 0.0,
            "drops_per_minute": 0.1,
            # A drop loses whole libairspy transfers.
            "drop_samples": [65536, 262144],
        },
        "airspy_rx writes int16 IQ by default (12-bit codes less 2048, shifted left by 4). No off-centre tuning: "
        "the low-IF tuner leaves no spike at DC.")
    return {preset.name: preset for preset in (rtl, generic, hackrf, pluto, b200, airspy)}


#: Every device preset by name.
DEVICES: dict[str, DevicePreset] = _devices()


def device_names() -> list[str]:
    """Names of the device presets, in the order of :data:`DEVICES`."""
    return list(DEVICES)


def get_device(name: str) -> DevicePreset:
    """The preset called ``name``.

    Raises
    ------
    ValueError
        For an unknown name; the message lists the known ones.
    """
    try:
        return DEVICES[name]
    except KeyError:
        raise ValueError(f"unknown SDR device {name!r}; known: {', '.join(DEVICES)}") from None


def apply_device(scenario: Scenario, name: str) -> Scenario:
    """``scenario`` recorded with the device ``name``: its ``[receiver]`` keys replaced by the preset's.

    Raises
    ------
    ValueError
        For an unknown device (the message lists the known ones).
    """
    return scenario.replace(receiver=get_device(name).receiver_table())

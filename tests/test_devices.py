"""The SDR device presets: applied to a scenario, each shapes the simulated capture the way docs/devices.md says.

A short capture of each preset (direct path only) is measured with
receiver-side statistics: the rate, format and ADC levels of what is
written, the DC of the rails, the LO leakage's level against the capture's
signal power (the same scenario without any impairment), the IQ imbalance
found by regressing the capture on the same capture without it, and, over
ten minutes, the AGC steps and the drops. docs/devices.md's figure table is
checked value by value against the presets.
"""

from __future__ import annotations

import ast
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from dtmbnav_core.iqformat import decode, get_format
from dtmbnav_core.records import Track
from receiver.mixer import check_channel_offset
from receiver.resample import resampling_ratio
from sim.devices import AD936X_PHASE_NOISE, DEVICES, apply_device, get_device
from sim.frontend import IMPAIRMENT_DEFAULTS
from sim.oscillator import clock_parameters
from sim.rf import CaptureGenerator
from sim.scenario import Scenario, load_scenario, scenario_from_dict, scenario_to_toml

DOCS = Path(__file__).resolve().parents[1] / "docs" / "devices.md"
#: The devices the project records with; rtl-sdr-generic is the crystal-oscillator twin of rtl-sdr.
EXPECTED = ("rtl-sdr", "rtl-sdr-generic", "hackrf-one", "plutosdr", "usrp-b200", "airspy-r2")
#: Image rejection, dB, of each preset's IQ imbalance, worked out by hand from
#: 10 log10((1 + g^2 + 2 g cos phi) / (1 + g^2 - 2 g cos phi)): 0.5 dB / 3 deg gives 4.2376 / 0.006420, 28.2 dB;
#: 0.02 dB / 0.2 deg gives 4.00922 / 1.75e-5, 53.6 dB. The balanced presets have no image at all.
IMAGE_REJECTION_DB = {"hackrf-one": 28.2, "plutosdr": 53.6, "usrp-b200": 53.6}
TOWER = np.array([2000.0, 2200.0])


def walking(seconds: float) -> Track:
    """A walk at 1.4 m/s towards the tower."""
    t = np.arange(0.0, seconds, 0.01)
    unit = TOWER / np.hypot(*TOWER)
    return Track(t, unit[0] * 1.4 * t, unit[1] * 1.4 * t, np.full_like(t, np.arctan2(unit[0], unit[1])),
                 np.full_like(t, 1.4))


def generator(name: str, seconds: float = 0.02, **receiver) -> CaptureGenerator:
    """The default scenario recorded with device ``name`` (direct path only), ``receiver`` keys replaced after."""
    scn = apply_device(Scenario(), name).replace(channel={"ground_reflection": False, "rician_k_db": None})
    return CaptureGenerator(scn.replace(receiver=receiver), walking(seconds + 1.0), seconds=seconds)


def rails(gen: CaptureGenerator) -> np.ndarray:
    """The interleaved rails the capture file holds, in the format's storage type."""
    return np.concatenate(list(gen.quantised_chunks(1 << 20)))


def samples(gen: CaptureGenerator) -> np.ndarray:
    """The capture decoded as the receiver reads it (full scale 1), complex128."""
    return decode(rails(gen), gen.scenario.receiver.sample_format).astype(np.complex128)


# ---------------------------------------------------------------- the scenario a preset gives


@pytest.mark.parametrize("name", EXPECTED)
def test_a_preset_replaces_the_front_end_keys_and_keeps_the_scenarios_own(name):
    base = load_scenario("park-loop-cw").replace(receiver={"cn_db": 9.0, "bulk_cfo_hz": 1234.0,
                                                           "iq_gain_db": 7.0, "lo_leakage_dbc": -3.0})
    scn = apply_device(base, name)
    table = get_device(name).receiver_table()
    for key, value in table.items():
        got = getattr(scn.receiver, key)
        if key == "clock":
            assert (got.preset, got.offset_ppb, got.drift_adev) == (value["preset"], value["offset_ppb"],
                                                                   value["drift_adev"])
        else:
            assert got == value, key
    # The keys a device does not fix keep the scenario's values.
    assert (scn.receiver.cn_db, scn.receiver.bulk_cfo_hz) == (9.0, 1234.0)
    assert (scn.walk, scn.tower, scn.seed) == (base.walk, base.tower, base.seed)
    assert scenario_from_dict(tomllib.loads(scenario_to_toml(scn))) == scn


@pytest.mark.parametrize("name", EXPECTED)
def test_the_rate_format_and_clock_are_ones_the_project_reads(name):
    receiver = get_device(name).receiver
    up, down = resampling_ratio(receiver["sample_rate_hz"])
    assert up > 0 and down > 0
    check_channel_offset(-receiver["tuning_offset_hz"], receiver["sample_rate_hz"])
    offset, adev = clock_parameters(apply_device(load_scenario("park-loop-cw"), name), rng=None)
    assert offset == receiver["clock"]["offset_ppb"] * 1e-9 and adev == receiver["clock"]["drift_adev"]


def test_a_preset_cannot_be_changed_in_place():
    preset = get_device("hackrf-one")
    table = preset.receiver_table()
    table["phase_noise_dbc_hz"][0][1] = 0.0
    table["clock"]["offset_ppb"] = 0.0
    assert preset.receiver["phase_noise_dbc_hz"][0][1] != 0.0
    assert preset.receiver["clock"]["offset_ppb"] != 0.0
    with pytest.raises(TypeError):
        preset.receiver["sample_rate_hz"] = 1.0  # type: ignore[index]


def test_an_unknown_device_names_the_known_ones():
    with pytest.raises(ValueError) as excinfo:
        apply_device(Scenario(), "rtlsdr")
    assert all(name in str(excinfo.value) for name in EXPECTED)


# ---------------------------------------------------------------- what a preset does to the capture


@pytest.mark.parametrize("name", EXPECTED)
def test_the_capture_has_the_presets_rate_format_and_adc_levels(name):
    receiver = get_device(name).receiver
    gen = generator(name)
    codes = rails(gen)
    fmt = get_format(receiver["sample_format"])
    assert codes.dtype == fmt.dtype and len(codes) == 2 * round(0.02 * receiver["sample_rate_hz"])
    # An ADC of adc_bits bits across the format's width moves in steps of 2 ** (width - bits) codes, and no coarser.
    step = 2 ** (8 * fmt.dtype.itemsize - receiver["adc_bits"])
    levels = codes.astype(np.int64) - int(fmt.offset)
    assert np.all(levels % step == 0)
    assert np.any(levels % (2 * step) != 0)


def test_the_rtl_sdr_bytes_centre_on_127_4():
    """The preset's adc_dc_lsb puts the cu8 bytes' mean where gr-osmosdr measured it (docs/devices.md)."""
    codes = rails(generator("rtl-sdr", 0.1)).astype(np.float64)
    # 240 000 samples at about 32 codes rms per rail: the mean scatters by 0.07 code.
    assert np.mean(codes[0::2]) == pytest.approx(127.4, abs=0.3)
    assert np.mean(codes[1::2]) == pytest.approx(127.4, abs=0.3)
    # Against the same capture without the ADC's DC the shift is exact to the rounding's dither.
    plain = rails(generator("rtl-sdr", 0.1, adc_dc_lsb=[0.0, 0.0])).astype(np.float64)
    np.testing.assert_allclose(np.mean((codes - plain).reshape(-1, 2), axis=0), [-0.6, -0.6], atol=0.02)


@pytest.mark.parametrize(("name", "leakage_dbc"), [("hackrf-one", -20.0), ("plutosdr", -60.0), ("usrp-b200", -60.0),
                                                   ("rtl-sdr", None), ("airspy-r2", None)])
def test_the_dc_spike_has_the_presets_level(name, leakage_dbc):
    """The capture's mean less that of the same scenario without any impairment (which also gives the signal power;
    C/N 60 dB: the noise adds 1e-6 to it) is the LO leakage, at the preset's level and phase (0 deg in every preset),
    or, without leakage, the ADC's DC."""
    receiver = get_device(name).receiver
    z = samples(generator(name, cn_db=60.0))
    signal = samples(generator(name, cn_db=60.0, **IMPAIRMENT_DEFAULTS))
    power = np.mean(np.abs(signal - np.mean(signal)) ** 2)
    dc = np.mean(z) - np.mean(signal)
    if leakage_dbc is None:
        # The RTL-SDR's bytes centre 0.6 LSB of its 8-bit ADC below the simulator's 128 (the decoder's 127.4
        # applies to both captures alike).
        lsb = 2.0 / 2 ** receiver["adc_bits"]
        assert dc == pytest.approx(complex(*receiver["adc_dc_lsb"]) * lsb, abs=1e-4)
    else:
        assert 10 * np.log10(abs(dc) ** 2 / power) == pytest.approx(leakage_dbc, abs=0.3)
        assert abs(math.degrees(np.angle(dc))) < 2.0


@pytest.mark.parametrize("name", EXPECTED)
def test_the_iq_imbalance_in_the_capture_is_the_presets(name):
    """Regressing the capture on the same capture with the imbalance off, ``y = mu z + nu conj(z) + c``, gives
    ``g exp(-j phi) = 2 mu - 1`` and ``g exp(j phi) = 1 - 2 nu`` (sim.frontend's convention) and the image rejection
    ``|mu / nu| ** 2``, worked out by hand in IMAGE_REJECTION_DB."""
    receiver = get_device(name).receiver
    y = samples(generator(name))
    z = samples(generator(name, iq_gain_db=0.0, iq_phase_deg=0.0))
    (mu, nu, _), *_ = np.linalg.lstsq(np.stack([z, np.conj(z), np.ones_like(z)], axis=1), y, rcond=None)
    g = abs(2 * mu - 1)
    assert 20 * np.log10(g) == pytest.approx(receiver["iq_gain_db"], abs=0.005)
    assert math.degrees(np.angle(1 - 2 * nu)) == pytest.approx(receiver["iq_phase_deg"], abs=0.02)
    if name in IMAGE_REJECTION_DB:
        assert 10 * np.log10(abs(mu / nu) ** 2) == pytest.approx(IMAGE_REJECTION_DB[name], abs=0.3)
    else:
        assert abs(nu) < 1e-4


@pytest.mark.parametrize("name", EXPECTED)
def test_the_agc_steps_and_drops_of_ten_minutes_follow_the_preset(name):
    """Ten minutes of schedule (nothing rendered): the counts are Poisson about the preset's rates, the AGC moves by
    its step, and each drop loses a length in its range; the file is shorter by what was dropped."""
    receiver = get_device(name).receiver
    gen = generator(name, 600.0)
    step_at, level = gen.frontend.agc_steps
    drops = gen.drops()
    for count, per_minute in ((len(step_at), receiver["agc_steps_per_minute"] if receiver["agc_step_db"] else 0.0),
                              (len(drops.samples), receiver["drops_per_minute"])):
        expected = 10.0 * per_minute
        assert abs(count - expected) <= 4.0 * math.sqrt(expected)
    assert np.all(np.abs(np.diff(np.concatenate([[0], level]))) == 1)
    low, high = receiver["drop_samples"]
    assert np.all((drops.samples >= low) & (drops.samples <= high))
    assert gen.capture_samples == gen.num_samples - int(np.sum(drops.samples))


def test_the_ad936x_profile_integrates_to_the_documented_rms_phase():
    """docs/devices.md: the AD936x profile integrates (100 Hz to 4 MHz, log-log between its points, flat outside) to
    0.21 deg rms, the Ettus 1.0 deg at 3.5 GHz scaled to 666 MHz."""
    offsets, levels = np.array(AD936X_PHASE_NOISE).T
    f = np.geomspace(100.0, 4e6, 200_001)
    ssb = 10 ** (np.interp(np.log10(f), np.log10(offsets), levels) / 10)
    rms_rad = math.sqrt(np.sum(0.5 * (ssb[1:] + ssb[:-1]) * np.diff(f)) * 2.0)
    assert math.degrees(rms_rad) == pytest.approx(0.21, abs=0.01)
    assert 1.0 * 666e6 / 3.5e9 == pytest.approx(0.19, abs=0.005)


# ---------------------------------------------------------------- the figure table


def figure_rows() -> list[dict[str, str]]:
    """The rows of docs/devices.md's figure table (device, figure, value, source, sweep range)."""
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("## Every figure, its source and the sweep around it"):]
    section = section[:section.index("\n## ")]
    rows = []
    for line in section.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) == 5 and cells[0].startswith("`"):
            rows.append(dict(zip(("device", "figure", "value", "source", "sweep"), cells)))
    return rows


def documented_value(cell: str):
    """A value cell (one backticked literal, ``none`` for a key left out) as Python."""
    literal = re.fullmatch(r"`([^`]*)`", cell).group(1)
    if literal == "none":
        return None
    try:
        return ast.literal_eval(literal)
    except (ValueError, SyntaxError):
        return literal


def preset_figures(name: str) -> dict[str, object]:
    """A preset's figures by key, the clock's as ``clock.offset_ppb`` and ``clock.drift_adev``."""
    table = get_device(name).receiver_table()
    clock = table.pop("clock")
    assert clock["preset"] == "custom"
    return {**table, "clock.offset_ppb": clock["offset_ppb"], "clock.drift_adev": clock["drift_adev"]}


def source_ids() -> set[str]:
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("## Sources"):]
    return set(re.findall(r"^\| `([a-z0-9-]+)` \|", section, re.MULTILINE))


def test_the_figure_table_gives_every_preset_value_a_source_and_a_sweep_range():
    rows = figure_rows()
    ids = source_ids()
    seen: dict[tuple[str, str], dict[str, str]] = {}
    for row in rows:
        for device in re.findall(r"`([^`]+)`", row["device"]):
            key = (device, re.fullmatch(r"`([^`]+)`", row["figure"]).group(1))
            assert key not in seen, f"docs/devices.md: two rows for {key}"
            seen[key] = row
    assert {device for device, _ in seen} == set(DEVICES)
    cited = set()
    for name in DEVICES:
        figures = preset_figures(name)
        assert {key for device, key in seen if device == name} == set(figures), name
        for key, value in figures.items():
            row = seen[(name, key)]
            documented = documented_value(row["value"])
            if isinstance(value, (list, float, int)) and value is not None:
                np.testing.assert_allclose(documented, value, rtol=1e-12, err_msg=f"{name} {key}")
            else:
                assert documented == value, (name, key)
            named = ids & set(re.findall(r"`([a-z0-9-]+)`", row["source"]))
            assert named or "assumption:" in row["source"], f"docs/devices.md: {name} {key} has no source"
            assert row["sweep"], f"docs/devices.md: {name} {key} has no sweep range"
            cited |= named
    # Every source the page lists stands behind some figure.
    assert cited == ids, sorted(ids - cited)


def test_the_docs_have_a_section_for_every_device():
    text = DOCS.read_text(encoding="utf-8")
    for name in DEVICES:
        assert re.search(rf"^## .*`{re.escape(name)}`", text, re.MULTILINE), f"docs/devices.md: no section for {name}"

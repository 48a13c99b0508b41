"""The SDR device presets: valid scenarios, rates and formats the receiver reads, every figure sourced.

docs/devices.md expands every source id a preset cites and names every
preset, so the code and the page cannot drift apart. No capture is rendered
here: the front-end impairments are exercised where they are implemented.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import pytest

from dtmbnav_core.iqformat import get_format
from receiver.mixer import check_channel_offset
from receiver.resample import resampling_ratio
from sim.devices import DEVICES, STATED, DevicePreset, apply_device, device_names, get_device
from sim.oscillator import clock_parameters
from sim.scenario import FrontEndConfig, load_scenario, scenario_from_dict, scenario_to_toml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "devices.md"
#: The devices the brief names; rtl-sdr-generic is the crystal-oscillator twin of rtl-sdr.
EXPECTED = {"rtl-sdr", "rtl-sdr-generic", "hackrf-one", "plutosdr", "usrp-b200", "airspy-r2"}


@pytest.fixture(scope="module")
def base():
    return load_scenario("park-loop-cw")


def test_the_expected_devices_are_there():
    assert set(device_names()) == EXPECTED
    assert device_names() == list(DEVICES)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_a_preset_gives_a_scenario_that_round_trips(base, name):
    scn = apply_device(base, name)
    preset = get_device(name)
    for key, value in preset.receiver_table().items():
        got = getattr(scn.receiver, key)
        if key == "clock":
            assert (got.preset, got.offset_ppb, got.drift_adev) == (value["preset"], value["offset_ppb"],
                                                                   value["drift_adev"])
        else:
            assert got == value, key
    # The keys a device does not fix keep the scenario's values.
    assert scn.receiver.cn_db == base.receiver.cn_db
    assert scn.receiver.start_offset_s == base.receiver.start_offset_s
    assert (scn.walk, scn.tower, scn.seed) == (base.walk, base.tower, base.seed)
    again = scenario_from_dict(tomllib.loads(scenario_to_toml(scn)))
    assert again == scn


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_the_rate_format_and_clock_are_ones_the_project_reads(name):
    receiver = get_device(name).receiver
    fmt = get_format(receiver["sample_format"])
    up, down = resampling_ratio(receiver["sample_rate_hz"])
    assert up > 0 and down > 0
    check_channel_offset(-receiver["tuning_offset_hz"], receiver["sample_rate_hz"])
    if receiver["adc_bits"] is not None:
        assert 1 <= receiver["adc_bits"] <= 8 * fmt.dtype.itemsize
    offset, adev = clock_parameters(apply_device(load_scenario("park-loop-cw"), name), rng=None)
    assert offset == receiver["clock"]["offset_ppb"] * 1e-9 and adev == receiver["clock"]["drift_adev"]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_every_key_has_a_source_and_only_front_end_keys_are_set(name):
    preset = get_device(name)
    fields = set(FrontEndConfig.__dataclass_fields__)
    assert set(preset.receiver) <= fields
    # A device fixes everything about itself, and none of the scenario's own settings.
    assert not set(preset.receiver) & {"cn_db", "agc_backoff_db", "start_offset_s", "bulk_cfo_hz", "iq_conjugate"}
    assert set(preset.sources) == preset.sourced_keys()
    assert all(preset.sources[key] and all(isinstance(s, str) for s in preset.sources[key]) for key in preset.sources)
    assert preset.description and preset.practice


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_the_values_are_physically_sensible(name):
    receiver = get_device(name).receiver
    assert math.isfinite(receiver["clock"]["offset_ppb"]) and 0 < receiver["clock"]["drift_adev"] < 1e-6
    if receiver["lo_leakage_dbc"] is not None:
        assert receiver["lo_leakage_dbc"] < 0
    assert abs(receiver["iq_gain_db"]) < 3 and abs(receiver["iq_phase_deg"]) < 10
    profile = receiver["phase_noise_dbc_hz"]
    offsets = [point[0] for point in profile]
    assert offsets == sorted(offsets) and all(-180 < point[1] < -60 for point in profile)
    low, high = receiver["drop_samples"]
    assert 1 <= low <= high


def test_a_preset_cannot_be_changed_in_place():
    preset = get_device("hackrf-one")
    table = preset.receiver_table()
    table["phase_noise_dbc_hz"][0][1] = 0.0
    table["clock"]["offset_ppb"] = 0.0
    assert preset.receiver["phase_noise_dbc_hz"][0][1] != 0.0
    assert preset.receiver["clock"]["offset_ppb"] != 0.0
    with pytest.raises(TypeError):
        preset.receiver["sample_rate_hz"] = 1.0  # type: ignore[index]
    assert isinstance(preset, DevicePreset)


def test_an_unknown_device_names_the_known_ones(base):
    with pytest.raises(ValueError) as excinfo:
        apply_device(base, "rtlsdr")
    assert all(name in str(excinfo.value) for name in EXPECTED)


def test_the_docs_name_every_device_and_expand_every_source_id():
    text = DOCS.read_text(encoding="utf-8")
    for name, preset in DEVICES.items():
        assert re.search(rf"^## .*`{re.escape(name)}`", text, re.MULTILINE), f"docs/devices.md: no section for {name}"
        for sid in preset.source_ids():
            assert re.search(rf"^\| `{re.escape(sid)}` \|", text, re.MULTILINE), \
                f"docs/devices.md does not expand the source id {sid!r} ({name})"
    assert f"| `{STATED}` |" in text

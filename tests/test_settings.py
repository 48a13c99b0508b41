"""Dotted settings of nested configurations (``dtmbnav evaluate/fuse --set``)."""

import dataclasses

import pytest

from dtmbnav_core.settings import parse_setting, setting_names, with_settings
from fusion.integrity import IntegrityConfig
from fusion.run import FusionConfig


def test_settings_reach_nested_fields_by_type_and_leave_the_original_alone():
    base = FusionConfig()
    config = with_settings(base, [("integrity.rate_sigma_mps", "0.05"), ("integrity.enabled", "off"),
                                  ("n_particles", "2000"), ("clock_allan_deviation", "1e-9"),
                                  ("heading_range", "si")])
    assert config.integrity == dataclasses.replace(IntegrityConfig(), rate_sigma_mps=0.05, enabled=False)
    assert (config.n_particles, config.clock_allan_deviation, config.heading_range) == (2000, 1e-9, "si")
    assert isinstance(config.n_particles, int) and base == FusionConfig()
    # Later settings win; an optional field takes "none".
    assert with_settings(config, [("clock_allan_deviation", "none")]).clock_allan_deviation is None


def test_every_scalar_field_is_named_once():
    names = setting_names(FusionConfig())
    assert len(names) == len(set(names))
    assert {"integrity.rate_sigma_mps", "noise.heading_rad", "paths.min_path_age_s", "seed"} <= set(names)
    assert "integrity" not in names


@pytest.mark.parametrize("setting, message", [
    (("integrity.rate_sigma", "0.1"), "unknown setting 'integrity.rate_sigma'; known: noise.position_m"),
    (("integrity", "1"), "is a group: set its fields (enabled, window"),
    (("seed.x", "1"), "seed has no fields"),
    (("n_particles", "1.5"), "must be int"),
    (("integrity.enabled", "maybe"), "true or false"),
    (("integrity.rate_sigma_mps", "-1"), "rate_sigma_mps must be >= 0"),  # the configuration's own check
])
def test_bad_settings_say_what_is_wrong(setting, message):
    with pytest.raises(ValueError) as exc:
        with_settings(FusionConfig(), [setting])
    assert message in str(exc.value)


def test_parse_setting():
    assert parse_setting(" integrity.window = 30 ") == ("integrity.window", "30")
    assert parse_setting("heading_range=") == ("heading_range", "")
    for bad in ("integrity.window", "=3", ""):
        with pytest.raises(ValueError, match="NAME=VALUE"):
            parse_setting(bad)

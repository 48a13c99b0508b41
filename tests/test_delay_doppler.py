"""Delay-Doppler map: paths under a chip apart, separated by their Doppler, against constructed CIRs."""

import numpy as np
import pytest

from receiver.delay_doppler import CHECK_FRAMES, DopplerConfig, FirstPathDoppler, delay_doppler_map, doppler_lines
from receiver.paths import pulse_tables

FRAME = 4200            # PN420 frame length, samples
PERIOD = 255            # PN420 m-sequence period: the CIR's pulse is periodic over it
LAG0, LAGS = -83, 165   # the path tracker's span


def pulse(x):
    table, _ = pulse_tables(PERIOD, 32)
    return np.interp(np.mod(x, PERIOD), np.arange(len(table)) / 32, table)


def street_corner_cir(n=2048, seed=0):
    """The street-out corner: a direct path 17 dB under a wall reflection 0.6 sample later, Dopplers 2.65 Hz apart;
    the frame windows step one and then two samples away from the nominal grid (the receiver clock drifting)."""
    rng = np.random.default_rng(seed)
    frame_index = 500 + np.arange(n)
    offsets = np.where(np.arange(n) < 700, 0, np.where(np.arange(n) < 1500, 1, 3))
    window_start = 123_456 + frame_index * FRAME + offsets
    t = np.arange(n) * FRAME / 7.56e6
    paths = [(10.0, 10 ** (-17 / 20), +1.30), (10.6, 1.0, -1.35)]   # (delay samples, amplitude, Doppler Hz)
    lags = LAG0 + np.arange(LAGS)
    taps = sum(a * np.exp(2j * np.pi * f * t)[:, None] * pulse(lags[None, :] - (d - offsets[:, None]))
               for d, a, f in paths)
    taps = taps + 1e-3 * (rng.standard_normal(taps.shape) + 1j * rng.standard_normal(taps.shape))
    return taps.astype(np.complex64), window_start, frame_index, paths


def test_two_paths_under_a_chip_apart_separate_by_their_doppler():
    taps, start, index, paths = street_corner_cir()
    dd = delay_doppler_map(taps, start, index, LAG0, FRAME, np.arange(4, 17))
    lines = doppler_lines(dd, floor_db=-25.0)
    wall, direct = lines[0], lines[1]
    bin_hz = dd.doppler_hz[1] - dd.doppler_hz[0]
    assert wall.doppler_hz == pytest.approx(-1.35, abs=bin_hz) and direct.doppler_hz == pytest.approx(1.30, abs=bin_hz)
    assert direct.power_db == pytest.approx(-17.0, abs=1.0)
    # Each line's delay profile is its own path's: the direct peaks at 10, the wall (10.6) at 11.
    assert (direct.delay_samples, wall.delay_samples) == (10, 11)
    # The windows' steps are followed (a path stays in its column): the wall's peak is its full amplitude there.
    k = np.argmin(np.abs(dd.doppler_hz - (-1.35)))
    assert np.abs(dd.spectrum[k - 2:k + 3, 11 - 4]).max() == pytest.approx(pulse(0.4), rel=0.03)
    assert len(lines) == 2                       # nothing else within 25 dB (Hann sidelobes, noise)


def test_frames_must_be_consecutive_and_inside_the_span():
    taps, start, index, _ = street_corner_cir(n=64)
    with pytest.raises(ValueError, match="consecutive"):
        delay_doppler_map(taps, start, index * 2, LAG0, FRAME, np.arange(4, 17))
    with pytest.raises(ValueError, match="leave the CIR span"):
        delay_doppler_map(taps, start, index, LAG0, FRAME, np.arange(75, 85))


def corner_batches(paths, n=4096, batch=128, seed=1):
    """Batches of (taps, window_start, frame_index) of constructed paths (delay, amplitude, Doppler), in order."""
    rng = np.random.default_rng(seed)
    index = np.arange(n)
    offsets = (index >= 2000).astype(int)
    t = index * FRAME / 7.56e6
    lags = LAG0 + np.arange(LAGS)
    taps = sum(a * np.exp(2j * np.pi * f * t)[:, None] * pulse(lags[None, :] - (d - offsets[:, None]))
               for d, a, f in paths)
    taps = taps + 1e-3 * (rng.standard_normal(taps.shape) + 1j * rng.standard_normal(taps.shape))
    followed = max(paths, key=lambda p: p[1])     # the tracked pair's amplitude follows its stronger member
    amplitude = followed[1] * np.exp(2j * np.pi * followed[2] * t)
    for lo in range(0, n, batch):
        s = slice(lo, lo + batch)
        yield taps[s].astype(np.complex64), index[s] * FRAME + offsets[s], index[s], amplitude[s], offsets[s]


def run_resolver(paths, tracked_delay):
    table, _ = pulse_tables(PERIOD, 32)
    resolver = FirstPathDoppler(DopplerConfig(frames=CHECK_FRAMES), table, 32, LAG0, FRAME)
    return [resolver.update(taps, start, index, tracked_delay - offsets[-1], amplitude)
            for taps, start, index, amplitude, offsets in corner_batches(paths)]


def test_first_path_moves_to_the_direct_line_under_a_stronger_reflection():
    """The street corner: the tracked pair (10.6 + 10.0) follows the wall; the direct path's line is at +1.30 Hz,
    shared with a diffuse cluster 0.65 sample after it that outweighs it by 10 dB (so its line's delay profile
    peaks later than the wall's): the super-resolved line still shows the direct path first."""
    paths = [(10.0, 10 ** (-17 / 20), +1.30), (10.65, 10 ** (-7 / 20), +1.30), (10.6, 1.0, -1.35)]
    corrections = run_resolver(paths, tracked_delay=10.45)
    assert corrections[:15] == [0.0] * 15                               # until a map's worth of frames
    assert np.all(np.abs(np.array(corrections[16:]) - 2.65) < 0.25)


@pytest.mark.parametrize("paths, tracked", [
    # line of sight: the direct path is the strongest and is tracked
    ([(10.0, 1.0, +1.30), (10.65, 10 ** (-12 / 20), +1.30), (12.0, 10 ** (-6 / 20), -1.35)], 10.0),
    # a scatter line at another Doppler, 0.65 sample after the tracked direct path: later, so not the direct path
    ([(10.0, 10 ** (-20 / 20), 0.0), (10.65, 10 ** (-12 / 20), +2.6), (11.5, 1.0, 0.0)], 10.0),
])
def test_no_correction_where_the_tracked_first_path_is_the_earliest(paths, tracked):
    assert set(run_resolver(paths, tracked)) == {0.0}

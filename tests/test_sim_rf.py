"""The RF simulator against physics: frame structure, power, SI, Doppler, clock, blockage, noise.

Every check measures the generated IQ with simple receiver-side operations
(header correlation, FFT of a frame body) and compares with the geometry, the
standard's tables and the truth record.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core import gb20600
from dtmbnav_core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav_core.gb20600 import PnMode
from dtmbnav_core.records import Track
from sim.block_synthesis import (BAND_EDGE, RATE_TOLERANCE_SYMBOLS, choose_layout, combine_kernel, combine_reference,
                                 path_spectrum_kernel, path_spectrum_reference, window_plan_kernel,
                                 window_plan_reference)
from sim.frames import FrameConfig, FrameSource, carriers_kernel, carriers_reference
from sim.rf import CaptureGenerator
from sim.scenario import Building, ClockConfig, Scenario, load_scenario
from sim.transmitter import (multipath_kernel, multipath_reference, pulse_spectrum, pulse_table, shape_kernel,
                             shape_reference, shaping_pulse, srrc_pulse)
from sim.walk import simulate_walk

RS = gb20600.SYMBOL_RATE_HZ
FC = 666e6
TOWER = np.array([2000.0, 2200.0])


def line_track(speed_mps: float = 0.0, towards_tower: bool = True, seconds: float = 3.0,
               start=(0.0, 0.0)) -> Track:
    """Constant-velocity straight line (speed 0: standing still) along the line to the tower."""
    t = np.arange(0.0, seconds, 0.01)
    bearing = TOWER - np.asarray(start)
    unit = bearing / np.hypot(*bearing) * (1.0 if towards_tower else -1.0)
    x, y = start[0] + unit[0] * speed_mps * t, start[1] + unit[1] * speed_mps * t
    heading = np.full_like(t, np.arctan2(unit[0], unit[1]))
    return Track(t, x, y, heading, np.full_like(t, speed_mps))


def quiet(offset_ppb: float = 0.0, **receiver) -> Scenario:
    """Direct path only, no noise, ideal (or given constant-offset) clock, cf32."""
    return Scenario().replace(
        receiver={"cn_db": float("inf"), "sample_format": "cf32",
                  "clock": ClockConfig("custom", offset_ppb, 0.0), **receiver},
        channel={"ground_reflection": False, "rician_k_db": None})


def header_correlations(gen: CaptureGenerator, z: np.ndarray, lag: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Correlation of each complete received header with its known symbols (fs = Rs)."""
    truth = gen.frame_truth()
    length = gen.frame_config.pn_mode.value.header_length
    starts = np.rint(truth.t_s * gen.sample_rate_hz).astype(int) + lag
    keep = starts + length <= len(z)
    values = [np.vdot(gen.frames.header(gen.frame_config.header_phase(int(f))), z[s: s + length])
              for s, f in zip(starts[keep], truth.frame_number[keep])]
    return truth.t_s[keep], np.array(values)


def phase_slope_hz(t_s: np.ndarray, values: np.ndarray) -> float:
    return np.polyfit(t_s, np.unwrap(np.angle(values)), 1)[0] / (2 * np.pi)


# ---------------------------------------------------------------- kernels

def test_pulse_is_unit_energy_and_nyquist():
    table = pulse_table(span=24, taper=8)
    x = np.arange(-24 * 512, 24 * 512) / 512
    p = srrc_pulse(x)
    assert np.sum(p**2) / 512 == pytest.approx(1.0, abs=2e-3)
    # p * p is a raised cosine: 1 at lag 0, ~0 at other whole symbols.
    for lag in range(1, 4):
        assert abs(np.sum(p[lag * 512:] * p[: len(p) - lag * 512]) / 512) < 5e-3
    assert table.polyphase.shape == (513, 48)
    # The table holds the tapered pulse at unit energy.
    assert np.sum(table.polyphase[:-1] ** 2) / 512 == pytest.approx(1.0, rel=1e-12)


def test_tapered_pulse_is_the_srrc_in_its_core_and_band_limited():
    table = pulse_table()
    core = np.linspace(-(table.span - table.taper), table.span - table.taper, 999)
    np.testing.assert_allclose(shaping_pulse(core), srrc_pulse(core), rtol=1e-15, atol=0)
    assert np.all(shaping_pulse(np.array([-table.span - 0.5, table.span, table.span + 3.0])) == 0.0)
    # The spectrum on a DFT's harmonics equals the Fourier integral of the pulse (midpoint rule, 1/2048 symbol).
    period = 5000
    bins = np.array([0, 1234, 2500, 2620, 2700, 3000])
    x = (np.arange(-table.span * 2048, table.span * 2048) + 0.5) / 2048
    direct = [np.sum(shaping_pulse(x) * np.cos(2 * np.pi * b / period * x)) / 2048 * table.scale for b in bins]
    np.testing.assert_allclose(pulse_spectrum(table, bins, period), direct, rtol=0, atol=1e-9)
    # Unit energy, and what block synthesis leaves out beyond BAND_EDGE is below -70 dB.
    k = np.arange(-period, period + 1)
    energy = pulse_spectrum(table, k, period) ** 2 / period
    assert np.sum(energy) == pytest.approx(1.0, rel=1e-6)
    assert 10 * np.log10(np.sum(energy[np.abs(k) > BAND_EDGE * period])) < -70.0


def test_kernels_equal_their_numpy_references():
    rng = np.random.default_rng(5)
    table = pulse_table(span=8, oversampling=64, taper=4)
    symbols = rng.standard_normal(500) + 1j * rng.standard_normal(500)
    u = rng.uniform(120.0, 380.0, 400)
    np.testing.assert_allclose(shape_kernel(u, symbols, 100, table.polyphase, 64),
                               shape_reference(u, symbols, 100, table), rtol=1e-12, atol=1e-12)
    grid_u = 150.0 + np.cumsum(rng.uniform(0.9, 1.1, (3, 40)), axis=1) * 4
    coef = rng.standard_normal((3, 40)) + 1j * rng.standard_normal((3, 40))
    phase = rng.uniform(-3, 3, 40)
    args = (1000, 300, 2.0, 100, 5.0)  # samples 1000..1299 at 2 S/s (500..650 s), grid columns 100.. every 5 s
    np.testing.assert_allclose(
        multipath_kernel(*args, grid_u, coef, phase, symbols, 100, table.polyphase, 64),
        multipath_reference(*args, grid_u, coef, phase, symbols, 100, table), rtol=1e-12, atol=1e-12)


def test_block_synthesis_kernels_equal_their_numpy_references():
    rng = np.random.default_rng(8)
    layout = choose_layout(10e6, 2e-4, 1e-6, pulse_table(), batch_blocks=3)
    n_paths, nb = 5, layout.batch_blocks
    # Two clusters of paths (the last two 200 symbols behind) and a path that is silent in block 1.
    start = 1000.0 + rng.uniform(0, 3, n_paths) + np.array([0, 0, 0, 200, 200])
    path_u = start[:, None] + np.arange(nb + 1) * layout.block_samples * layout.rho * (1 + 3e-7)
    coef = rng.standard_normal((n_paths, nb + 1)) + 1j * rng.standard_normal((n_paths, nb + 1))
    coef[2, 1:3] = 0.0
    outputs = (np.empty(nb * n_paths, np.int64), np.empty((nb, n_paths), np.int64), np.zeros((nb, n_paths)),
               *(np.empty((nb, n_paths), np.complex128) for _ in range(3)))
    windows = window_plan_kernel(path_u, coef, layout.rho, layout.block_samples, layout.span,
                                 layout.window_symbols, layout.spread_symbols, *outputs)
    expected = window_plan_reference(path_u, coef, layout)
    assert windows == len(expected[0]) == 2 * nb
    np.testing.assert_array_equal(outputs[0][:windows], expected[0])
    np.testing.assert_array_equal(outputs[1], expected[1])
    assert outputs[1][1, 2] == -1
    for got, want in zip(outputs[2:], expected[2:]):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)

    spectra = (rng.standard_normal((windows, layout.window_symbols))
               + 1j * rng.standard_normal((windows, layout.window_symbols))).astype(np.complex64)
    bins = np.empty((2 * nb, layout.output_bins), np.complex64)
    path_spectrum_kernel(spectra, *outputs[1:], layout.pulse, layout.first_bin, bins)
    want = path_spectrum_reference(spectra, *outputs[1:], layout.pulse, layout.first_bin, layout.output_bins)
    # Single-precision sums: agree to float32 rounding of the largest bin.
    np.testing.assert_allclose(bins, want, rtol=0, atol=3e-6 * np.abs(want).max())

    phase = np.cumsum(rng.uniform(-2, 2, nb + 1))
    out = np.empty(nb * layout.block_samples, np.complex128)
    combine_kernel(bins, layout.block_samples, phase, 1 / layout.window_symbols, out)
    np.testing.assert_allclose(out, combine_reference(bins, layout.block_samples, phase, 1 / layout.window_symbols),
                               rtol=1e-9, atol=1e-12 * np.abs(out).max())

    draws = rng.integers(0, 256, (3, gb20600.DATA_LENGTH), dtype=np.uint8)
    source = FrameSource(FrameConfig())
    carriers = np.empty((3, gb20600.BODY_LENGTH), np.complex128)
    carriers_kernel(draws, source._points, source._bin_data, source._carriers_template, carriers)
    np.testing.assert_array_equal(carriers, carriers_reference(draws, source._points, source._bin_data,
                                                               source._carriers_template))


@pytest.mark.parametrize("rate_hz", [7.56e6, 10e6, 12.5e6, 16e6, 20e6, 9.1234567e6, 2.5e6])
def test_block_layout_carries_the_rate(rate_hz):
    layout = choose_layout(rate_hz, 1e-3, 5e-7, pulse_table())
    rho = RS / rate_hz
    drift = abs(layout.window_symbols / layout.output_bins - rho) * layout.block_samples
    assert drift <= RATE_TOLERANCE_SYMBOLS
    if rate_hz in (7.56e6, 10e6, 12.5e6, 16e6, 20e6):  # exact ratios with FFT-friendly sizes
        assert layout.window_symbols * rate_hz == pytest.approx(layout.output_bins * RS, rel=1e-15)
    # The window holds a block, the pulse at both ends and a spread of paths.
    assert layout.spread_symbols >= 32
    assert layout.window_symbols >= layout.rho * (layout.block_samples - 1) + 2 * layout.span + layout.spread_symbols


def _error_db(block: np.ndarray, exact: np.ndarray) -> float:
    return 10 * np.log10(np.mean(np.abs(block - exact) ** 2) / np.mean(np.abs(exact) ** 2))


@pytest.mark.parametrize("case", ["park-loop free-running 7.56 Msps", "street walls 10 Msps",
                                  "street walls 2.4 Msps", "fast 20 ppm 16 Msps"])
def test_block_synthesis_matches_the_exact_twin(case):
    """Walking, multipath, drifting clock: block synthesis within -50 dB of the sample-by-sample twin
    (below the symbol rate both shape with the pulse through the front end's anti-alias filter)."""
    if case.startswith("park-loop"):
        scn = load_scenario("park-loop").replace(receiver={"clock": ClockConfig("free-running")})
        rate, track = None, simulate_walk(scn).track
    elif case.startswith("street"):
        scn = load_scenario("street")
        rate, track = (2.4e6 if case.endswith("2.4 Msps") else 10e6), simulate_walk(scn).track
    else:  # a car at 30 m/s with a scatterer, and a clock 20 ppm off (sampling offset as large as tests use)
        scn = quiet(20e3, cn_db=20.0).replace(channel={"scatterers": [{"x_m": -300.0, "y_m": 250.0, "gain_db": -6.0}],
                                                      "rician_k_db": 10.0, "ground_reflection": True})
        rate, track = 16e6, line_track(30.0, seconds=3.0)
    start_s = 20.0 if case.startswith(("park", "street")) else 0.5
    block = CaptureGenerator(scn, track, start_s=start_s, seconds=2.0, sample_rate_hz=rate)
    exact = CaptureGenerator(scn, track, start_s=start_s, seconds=2.0, sample_rate_hz=rate, synthesis="exact")
    assert block.num_paths >= 4
    assert (block.pulse.lowpass is not None) == (block.sample_rate_hz < gb20600.SYMBOL_RATE_HZ)
    # Windows spread over the two seconds (the exact twin is slow); both are pure functions of the index.
    errors, power = [], []
    for first in np.linspace(block.first_sample, block.first_sample + block.num_samples - 20_000, 6).astype(int):
        a, b = block.clean_samples(first, 20_000), exact.clean_samples(first, 20_000)
        errors.append(np.mean(np.abs(a - b) ** 2))
        power.append(np.mean(np.abs(b) ** 2))
    assert 10 * np.log10(np.mean(errors) / np.mean(power)) < -50.0
    assert 10 * np.log10(max(errors) / min(power)) < -45.0


# ---------------------------------------------------------------- frame structure

@pytest.mark.parametrize("mode", ["PN420", "PN945"])
def test_header_phase_schedule_seen_by_correlation(mode):
    gen = CaptureGenerator(quiet(), line_track(), seconds=0.06, pn_mode=mode)
    z = np.concatenate(list(gen.chunks(1 << 16)))
    truth = gen.frame_truth()
    info = PnMode.parse(mode).value
    core = 1.0 - 2.0 * gb20600.pn_core(PnMode.parse(mode)).astype(float)
    core_spectrum = np.conj(np.fft.fft(core))
    found = []
    for t_s, frame in zip(truth.t_s, truth.frame_number):
        s = int(round(t_s * RS)) + info.preamble
        if s + info.period > len(z):
            break
        # Circular correlation of the received core against every cyclic shift of the PN core.
        corr = np.abs(np.fft.ifft(np.fft.fft(z[s: s + info.period]) * core_spectrum))
        # Peak at d: received chip n = core[(n - d) mod P]; it is header chip preamble + n,
        # i.e. core[(preamble + n + phase) mod P], so phase = -d - preamble (mod P).
        shift = int(np.argmax(corr))
        phase = (-shift - info.preamble) % info.period
        assert corr[shift] > 5 * np.partition(corr, -2)[-2]
        found.append((phase, int(gb20600.header_phase(PnMode.parse(mode), frame % info.frames_per_superframe))
                      % info.period))
    found = np.array(found)
    assert len(found) > 80
    np.testing.assert_array_equal(found[:, 0], found[:, 1])
    # The capture starts mid-superframe, and the frame numbers continue the transmitter's count.
    delay_s = truth.range_m[0] / SPEED_OF_LIGHT_MPS
    assert truth.frame_number[0] == int(np.ceil((0.0371 - delay_s) * RS / info.frame_length))
    assert np.all(np.diff(truth.frame_number) == 1)
    np.testing.assert_allclose(np.diff(truth.t_s), info.frame_duration_s, rtol=1e-9)


def test_header_body_power_and_mean_power():
    # At 10 Msps the sample instants sweep every fraction of a symbol: sampling the SRRC signal
    # at one fixed fraction (1 sample/symbol) would bias the power by up to ~roll-off/2.
    fs = 10e6
    gen = CaptureGenerator(quiet(), line_track(), seconds=0.1, sample_rate_hz=fs)
    z = gen.clean_samples(0, gen.num_samples)
    r = fs / RS
    starts = gen.frame_truth().t_s * fs
    starts = starts[starts + 4200 * r <= len(z)]
    header = np.mean([np.mean(np.abs(z[int(s + 20 * r): int(s + 400 * r)]) ** 2) for s in starts])
    body = np.mean([np.mean(np.abs(z[int(s + 440 * r): int(s + 4180 * r)]) ** 2) for s in starts])
    assert header / body == pytest.approx(2.0, rel=0.02)
    assert np.mean(np.abs(z) ** 2) == pytest.approx(gen.signal_power, rel=0.01)
    assert gen.signal_power == pytest.approx((420 * 2 + 3780) / 4200)


def test_si_on_the_36_carriers_nearest_dc():
    gen = CaptureGenerator(quiet(), line_track(), seconds=0.03)
    z = gen.clean_samples(0, gen.num_samples)
    si = gb20600.si_symbols(15)
    bins = gb20600.si_bins()
    assert sorted(bins) == list(range(18)) + list(range(3762, 3780))
    previous = None
    for s in np.rint(gen.frame_truth().t_s * RS).astype(int):
        if s + 4200 > len(z):
            break
        y = np.fft.fft(z[s + 420: s + 4200], norm="ortho")[bins]
        gain = np.vdot(si, y) / np.vdot(si, si)
        assert abs(gain) == pytest.approx(1.0, rel=0.05)
        assert np.linalg.norm(y - gain * si) / np.linalg.norm(gain * si) < 0.1
        if previous is not None:  # the same SI symbols in consecutive frames (what eq. 8 relies on)
            assert abs(np.vdot(previous, y)) / (np.linalg.norm(previous) * np.linalg.norm(y)) > 0.99
        previous = y


# ---------------------------------------------------------------- streaming

def _noisy_generator(seed=None, seconds=30_000 / RS, **kw):
    """Default scenario (noise, ground, diffuse, GNSS clock, ci8) plus a scatterer, walking."""
    scn = Scenario().replace(channel={"scatterers": [{"x_m": 30.0, "y_m": -20.0, "gain_db": -6.0}]})
    return CaptureGenerator(scn, line_track(1.4), seconds=seconds, seed=seed, **kw)


@pytest.fixture(scope="module")
def reference_stream():
    gen = _noisy_generator()
    return np.concatenate(list(gen.chunks(1 << 20))), np.concatenate(list(gen.quantised_chunks(1 << 20)))


@settings(max_examples=10, deadline=None)
@given(sizes=st.lists(st.integers(500, 12_000), min_size=1, max_size=4))
def test_chunk_size_invariance(reference_stream, sizes):
    floats, rails = reference_stream
    gen = _noisy_generator()
    for size in sizes:  # the same generator re-read with another chunk size gives the same stream
        assert np.array_equal(np.concatenate(list(gen.chunks(size))), floats)
    assert np.array_equal(np.concatenate(list(gen.quantised_chunks(sizes[0]))), rails)


def test_segment_equals_the_same_samples_of_the_full_capture(reference_stream):
    floats, _ = reference_stream
    segment = _noisy_generator(start_s=12_345 / RS, seconds=5_000 / RS)
    assert np.array_equal(np.concatenate(list(segment.chunks(3_000))), floats[12_345: 17_345])


def test_same_seed_same_bytes_other_seed_other_bytes(reference_stream):
    _, rails = reference_stream
    again = np.concatenate(list(_noisy_generator(seed=Scenario().seed).quantised_chunks(7_777)))
    other = np.concatenate(list(_noisy_generator(seed=Scenario().seed + 1).quantised_chunks(7_777)))
    assert again.tobytes() == rails.tobytes()
    assert other.tobytes() != rails.tobytes()
    assert np.mean(other == rails) < 0.2


def test_threads_give_the_same_bytes():
    # Short blocks (a 0.1 ms grid) so that a 60 000-sample capture spans several batches.
    gen = _noisy_generator(seconds=60_000 / RS, grid_step_s=1e-4)
    assert gen.layout.batch_samples < 30_000
    one = np.concatenate(list(gen.quantised_chunks(7_000)))
    again = _noisy_generator(seconds=60_000 / RS, grid_step_s=1e-4)
    three = np.concatenate(list(again.quantised_chunks(7_000, jobs=3)))
    assert three.tobytes() == one.tobytes()


# ---------------------------------------------------------------- motion, clock, blockage, noise

@pytest.mark.parametrize("towards", [True, False])
def test_moving_receiver_doppler(towards):
    speed = 3.0
    gen = CaptureGenerator(quiet(), line_track(speed, towards), seconds=0.3)
    z = gen.clean_samples(0, gen.num_samples)
    t_s, corr = header_correlations(gen, z)
    measured = phase_slope_hz(t_s, corr)
    ground = np.hypot(*TOWER)
    closing = speed * ground / np.hypot(ground, 150.0 - 1.2) * (1 if towards else -1)
    geometric = FC * closing / SPEED_OF_LIGHT_MPS
    assert abs(geometric) > 6.0
    assert measured == pytest.approx(geometric, rel=0.005)
    truth = gen.frame_truth()
    assert np.mean(truth.doppler_hz) == pytest.approx(geometric, rel=1e-3)
    assert np.mean(truth.radial_velocity_mps) == pytest.approx(closing, rel=1e-3)
    assert np.all(truth.clock_offset_hz == 0.0) and np.all(truth.los)


def _fit_header(gen: CaptureGenerator, z: np.ndarray, start: int, frame: int) -> tuple[float, complex]:
    """Sub-sample position and complex amplitude of a header echo near sample ``start``.

    Correlating the shaped header with its symbols gives ``A p(lag - delta)``
    (the PN is almost white): ``delta`` is the least-squares shift of the pulse.
    """
    header = gen.frames.header(gen.frame_config.header_phase(frame))
    lags = np.arange(-4, 5)
    corr = np.array([np.vdot(header, z[start + lag: start + lag + len(header)]) for lag in lags])
    best = (np.inf, 0.0, 0j)
    for shift in np.linspace(-1.0, 1.0, 2001):
        basis = srrc_pulse(lags - shift)
        amplitude = np.vdot(basis, corr) / np.vdot(basis, basis)
        best = min(best, (np.linalg.norm(corr - amplitude * basis), shift, amplitude), key=lambda b: b[0])
    return start + best[1], best[2] / np.vdot(header, header).real


def _peak_position(gen: CaptureGenerator, z: np.ndarray, start: int, frame: int) -> float:
    return _fit_header(gen, z, start, frame)[0]


def test_scatterer_echo_has_its_geometric_delay_and_gain():
    scatterer = (-300.0, 250.0)
    scn = quiet().replace(channel={"scatterers": [{"x_m": scatterer[0], "y_m": scatterer[1], "gain_db": -6.0}]})
    gen = CaptureGenerator(scn, line_track(), seconds=0.003)
    z = gen.clean_samples(0, gen.num_samples)
    truth = gen.frame_truth()
    direct_m = np.hypot(np.hypot(*TOWER), 148.8)
    echo_m = np.hypot(np.hypot(*(TOWER - scatterer)), 148.8) + np.hypot(*scatterer)
    excess = (echo_m - direct_m) / SPEED_OF_LIGHT_MPS * RS
    assert 4 < excess < 15  # 0.5 - 2 us, as in the street scenario
    start = int(round(truth.t_s[0] * RS))
    pos_d, amp_d = _fit_header(gen, z, start, int(truth.frame_number[0]))
    pos_e, amp_e = _fit_header(gen, z, start + int(round(excess)), int(truth.frame_number[0]))
    assert pos_e - pos_d == pytest.approx(excess, abs=0.05)
    assert abs(amp_e / amp_d) == pytest.approx(10 ** (-6 / 20), rel=0.05)
    # Carrier phase difference from the extra path length, -2 pi fc (excess length) / c.
    expected = np.exp(-2j * np.pi * FC * (echo_m - direct_m) / SPEED_OF_LIGHT_MPS)
    assert abs(np.angle(amp_e / amp_d / expected)) < 0.1


def test_header_delay_follows_the_range():
    """A fast receiver (150 m/s away): frame arrivals move with range / c."""
    track = line_track(150.0, towards_tower=False, seconds=2.5)
    moved = []
    for start_s in (0.0, 2.0):
        gen = CaptureGenerator(quiet(), track, start_s=start_s, seconds=0.003)
        z = gen.clean_samples(gen.first_sample, gen.num_samples)
        truth = gen.frame_truth()
        frame = int(truth.frame_number[0])
        measured = gen.first_sample + _peak_position(gen, z, int(round(truth.t_s[0] * RS)), frame)
        sent = (frame * 4200 / RS - 0.0371) * RS
        expected = sent + truth.range_m[0] / SPEED_OF_LIGHT_MPS * RS
        assert measured == pytest.approx(expected, abs=0.02)
        assert gen.first_sample + truth.t_s[0] * RS == pytest.approx(expected, abs=1e-6)
        moved.append((measured - sent, truth.range_m[0]))
    (delay_a, range_a), (delay_b, range_b) = moved
    assert range_b - range_a == pytest.approx(300 * np.hypot(*TOWER) / np.hypot(np.hypot(*TOWER), 148.8), rel=0.01)
    assert delay_b - delay_a == pytest.approx((range_b - range_a) / SPEED_OF_LIGHT_MPS * RS, abs=0.03)


def test_clock_offset_is_the_apparent_cfo():
    gen = CaptureGenerator(quiet(40.0, bulk_cfo_hz=100.0), line_track(), seconds=0.2)
    truth = gen.frame_truth()
    assert truth.clock_offset_hz == pytest.approx(-FC * 40e-9)
    t_s, corr = header_correlations(gen, gen.clean_samples(0, gen.num_samples))
    assert phase_slope_hz(t_s, corr) == pytest.approx(-FC * 40e-9 + 100.0, abs=0.01)


def test_conjugated_iq_flips_the_cfo():
    gen = CaptureGenerator(quiet(bulk_cfo_hz=250.0, iq_conjugate=True), line_track(), seconds=0.05)
    z = np.concatenate(list(gen.chunks(1 << 16)))
    assert phase_slope_hz(*header_correlations(gen, np.conj(z))) == pytest.approx(250.0, abs=0.05)
    assert phase_slope_hz(*header_correlations(gen, z)) == pytest.approx(-250.0, abs=0.05)


def test_preset_clock_draws_and_truth():
    gen = CaptureGenerator(Scenario(), line_track(), seconds=0.01)
    y = gen.oscillator.offset
    assert 0 < abs(y) <= 30e-9
    truth = gen.frame_truth()
    np.testing.assert_allclose(truth.clock_offset_hz, -FC * y, atol=FC * 1e-10)


def test_sampling_offset_stretches_the_frame_timing():
    y = 20e-6  # 20 ppm, with the tuner cancelling the LO part so headers stay coherent
    gen = CaptureGenerator(quiet(y * 1e9, bulk_cfo_hz=FC * y), line_track(), seconds=0.1)
    z = gen.clean_samples(0, gen.num_samples)
    first = int(round(gen.frame_truth().t_s[0] * RS))
    peaks, frames = [], []
    for m in range(int(len(z) / 4200) - 1):
        nominal = first + m * 4200
        header = gen.frames.header(gen.frame_config.header_phase(int(gen.frame_truth().frame_number[0]) + m))
        window = np.array([abs(np.vdot(header, z[nominal + lag: nominal + lag + 420])) for lag in range(0, 40)])
        peaks.append(nominal + np.argmax(window))
        frames.append(m)
    spacing = np.polyfit(frames, peaks, 1)[0]
    assert spacing / 4200 - 1 == pytest.approx(y, rel=0.02)
    np.testing.assert_allclose(np.diff(gen.frame_truth().t_s) * RS, 4200 * (1 + y), atol=1e-3)
    # The LO part of the same clock is -fc*y (cancelled here by the tuner): the headers stay coherent.
    assert abs(phase_slope_hz(*header_correlations(gen, z))) < 0.01


def test_blockage_attenuates_the_direct_path():
    building = Building([[90.0, 80.0], [130.0, 80.0], [130.0, 140.0], [90.0, 140.0]], attenuation_db=18.0)
    powers, los = [], []
    for buildings in ([], [building]):
        gen = CaptureGenerator(quiet().replace(channel={"buildings": buildings}), line_track(), seconds=0.01)
        powers.append(np.mean(np.abs(gen.clean_samples(0, gen.num_samples)) ** 2))
        los.append(gen.frame_truth().los)
    assert 10 * np.log10(powers[0] / powers[1]) == pytest.approx(18.0, abs=0.05)
    assert np.all(los[0]) and not np.any(los[1])


def test_noise_level_matches_cn_and_signal_is_band_limited():
    fs = 16e6
    gen = CaptureGenerator(quiet(cn_db=10.0), line_track(), seconds=0.02, sample_rate_hz=fs)
    clean = gen.clean_samples(0, gen.num_samples)
    noise = np.concatenate(list(gen.chunks(1 << 16))) / gen.frontend.agc_gain - clean
    carrier = np.mean(np.abs(clean) ** 2)
    assert carrier == pytest.approx(gen.signal_power, rel=0.02)
    assert np.mean(np.abs(noise) ** 2) == pytest.approx(carrier / 10.0 * fs / RS, rel=0.02)
    freq = np.fft.fftfreq(len(noise), 1 / fs)
    in_band = np.abs(freq) < RS / 2
    noise_band = np.sum(np.abs(np.fft.fft(noise)[in_band]) ** 2) / len(noise) ** 2
    assert noise_band == pytest.approx(carrier / 10.0, rel=0.03)
    spectrum = np.abs(np.fft.fft(clean)) ** 2
    assert np.sum(spectrum[np.abs(freq) > 0.53 * RS]) / np.sum(spectrum) < 1e-3


def test_simulate_writes_capture_and_truth(tmp_path):
    pytest.importorskip("sim.walk_io")
    import h5py

    from dtmbnav_core.h5io import read_columns
    from dtmbnav_core.iqformat import decode
    from receiver.capture import open_capture
    from sim.scenario import load_scenario
    from sim.simulate import simulate
    from sim.walk import simulate_walk

    scn = load_scenario("park-loop")
    result = simulate(scn, tmp_path / "sigmf", seconds=0.02, start_s=5.0, chunk_samples=40_000)
    src = open_capture(result.capture_path)
    assert src.num_samples == round(0.02 * RS) and src.sample_format == scn.receiver.sample_format
    assert src.center_hz == scn.tower.carrier_hz and src.metadata["dtmbnav:seed"] == scn.seed
    # The file holds exactly the generator's quantised stream for the walk's track.
    direct = CaptureGenerator(scn, simulate_walk(scn).track, start_s=5.0, seconds=0.02)
    expected = decode(np.concatenate(list(direct.quantised_chunks(1 << 20))), src.sample_format)
    assert np.array_equal(np.concatenate(list(src.chunks(10_000))), expected)
    frames = read_columns(result.truth_path, "truth/frames")
    assert 0 <= frames["t_s"].min() and frames["t_s"].max() < 0.02
    np.testing.assert_array_equal(frames["frame_number"], direct.frame_truth().frame_number)
    with h5py.File(result.truth_path, "r") as f:
        attrs = dict(f["truth/frames"].attrs)
    assert attrs["pn_mode"] == "PN420" and attrs["capture_start_s"] == pytest.approx(5.0)
    assert 'name = "park-loop-cw"' in attrs["scenario"]
    raw = simulate(scn, tmp_path / "raw", seconds=0.01, container="raw", sample_format="ci16", pn_mode="PN945")
    assert open_capture(raw.capture_path).sample_format == "ci16"
    assert read_columns(raw.truth_path, "truth/frames").keys() >= {"t_s", "doppler_hz", "clock_offset_hz", "los"}

"""The RF simulator against physics: frame structure, power, SI, Doppler, clock, blockage, noise.

Every check measures the generated IQ with simple receiver-side operations
(header correlation, FFT of a frame body) and compares with the geometry, the
standard's tables and the truth record.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav.core import gb20600
from dtmbnav.core.constants import SPEED_OF_LIGHT_MPS
from dtmbnav.core.gb20600 import PnMode
from dtmbnav.core.records import Track
from sim.rf import CaptureGenerator
from sim.scenario import Building, ClockConfig, Scenario
from sim.transmitter import (multipath_kernel, multipath_reference, pulse_table, shape_kernel, shape_reference,
                             srrc_pulse)

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
    table = pulse_table(span=24)
    x = np.arange(-24 * 512, 24 * 512) / 512
    p = srrc_pulse(x)
    assert np.sum(p**2) / 512 == pytest.approx(1.0, abs=2e-3)
    # p * p is a raised cosine: 1 at lag 0, ~0 at other whole symbols.
    for lag in range(1, 4):
        assert abs(np.sum(p[lag * 512:] * p[: len(p) - lag * 512]) / 512) < 5e-3
    assert table.polyphase.shape == (513, 48)


def test_kernels_equal_their_numpy_references():
    rng = np.random.default_rng(5)
    table = pulse_table(span=8, oversampling=64)
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

    from dtmbnav.core.h5io import read_columns
    from dtmbnav.core.iqformat import decode
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

"""IQ formats, capture writers and the capture reader: round trips and bad input."""

import io
import json
import re
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav_core import iqformat
from dtmbnav_core.records import Track
from receiver.capture import MissingCaptureOptions, TruncatedStream, capture_files, open_capture
from sim.capture_writer import CaptureWriter
from sim.rf import CaptureGenerator
from sim.scenario import Scenario

FORMATS = ["cu8", "ci8", "ci16", "cf32"]


def still_track(seconds: float = 2.0) -> Track:
    t = np.arange(0.0, seconds, 0.01)
    zero = np.zeros_like(t)
    return Track(t, zero, zero, zero, zero)


@pytest.fixture(scope="module")
def float_stream() -> np.ndarray:
    """20 ms of a default (noisy, multipath, ci8-scaled) scenario at 7.56 Msps."""
    gen = CaptureGenerator(Scenario(), still_track(), seconds=0.02)
    return np.concatenate(list(gen.chunks(50_000)))


# ---------------------------------------------------------------- iqformat

@settings(max_examples=50, deadline=None)
@given(fmt=st.sampled_from(FORMATS), seed=st.integers(0, 2**32 - 1), n=st.integers(1, 300))
def test_encode_decode_round_trip_within_half_lsb(fmt, seed, n):
    rng = np.random.default_rng(seed)
    z = (rng.uniform(-0.99, 0.99, n) + 1j * rng.uniform(-0.99, 0.99, n)).astype(np.complex64)
    back = iqformat.decode(iqformat.encode(z, fmt).tobytes(), fmt)
    spec = iqformat.get_format(fmt)
    lsb = 1.0 / spec.scale
    # cu8 is encoded about 128 and decoded about the drivers' 127.4: a constant the receiver removes as DC.
    back = back - np.complex64((spec.offset - spec.decode_offset) * lsb * (1 + 1j))
    tol = 0.5 * lsb + 1e-6 if fmt != "cf32" else 0.0
    assert back.dtype == np.complex64
    assert np.max(np.abs(back.real - z.real)) <= tol
    assert np.max(np.abs(back.imag - z.imag)) <= tol


def test_normalisation_matches_conventions():
    # cu8 decodes about the RTL-SDR drivers' centre, 127.4 (docs/devices.md).
    expected = [complex(0.6 / 128, -127.4 / 128), complex(127.6 / 128, 64.6 / 128)]
    assert np.allclose(iqformat.decode(bytes([128, 0, 255, 192]), "cu8"), expected, atol=1e-7)
    assert iqformat.decode(np.array([-128, 64], np.int8).tobytes(), "ci8")[0] == complex(-1, 0.5)
    assert iqformat.decode(np.array([-32768, 16384], "<i2").tobytes(), "ci16")[0] == complex(-1, 0.5)
    assert iqformat.decode(np.array([0.25, -3.0], "<f4").tobytes(), "cf32")[0] == complex(0.25, -3.0)


def test_encode_clips_to_the_format_range():
    assert iqformat.encode(np.array([2 - 2j]), "ci8").tolist() == [127, -128]
    assert iqformat.encode(np.array([2 - 2j]), "cu8").tolist() == [255, 0]
    assert iqformat.encode(np.array([2 - 2j]), "ci16").tolist() == [32767, -32768]


def test_sigmf_datatype_names_both_ways():
    for name, sigmf in [("cu8", "cu8"), ("ci8", "ci8"), ("ci16", "ci16_le"), ("cf32", "cf32_le")]:
        assert iqformat.get_format(name).sigmf_datatype == sigmf
        assert iqformat.from_sigmf_datatype(sigmf).name == name


@pytest.mark.parametrize("call", [lambda: iqformat.get_format("ci12"), lambda: iqformat.from_sigmf_datatype("ci16_be"),
                                  lambda: iqformat.decode(b"\x00\x01\x02", "ci8"),
                                  lambda: iqformat.decode(b"\x00\x01\x02\x03\x04\x05", "ci16"),
                                  lambda: iqformat.decode(np.array([np.nan, 0], "<f4").tobytes(), "cf32"),
                                  lambda: iqformat.encode(np.array([np.inf + 0j]), "ci8")])
def test_iqformat_rejects_bad_input(call):
    with pytest.raises(ValueError):
        call()


# ---------------------------------------------------------------- writer + reader

@pytest.mark.parametrize("container", ["sigmf", "raw"])
@pytest.mark.parametrize("fmt", FORMATS)
def test_capture_round_trip(tmp_path, float_stream, container, fmt):
    z = float_stream
    with CaptureWriter(tmp_path / "cap", container, fmt, 7.56e6, 666e6, start_utc_unix_ns=1_767_225_600_123_456_000,
                       description="test", project={"scenario": "custom", "seed": 7}) as writer:
        for part in np.array_split(z, 3):
            writer.write(iqformat.encode(part, fmt))
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
    src = open_capture(writer.capture_path)
    assert (src.sample_rate_hz, src.center_hz, src.sample_format, src.num_samples) == (7.56e6, 666e6, fmt, len(z))
    assert src.start_utc_unix_ns == 1_767_225_600_123_456_000
    back = np.concatenate(list(src.chunks(7_000)))
    info = iqformat.get_format(fmt)
    if fmt == "cf32":
        assert np.array_equal(back, z)
        return
    top = (np.iinfo(info.dtype).max - info.offset) / info.scale
    expect = np.clip(z.real, -1.0, top) + 1j * np.clip(z.imag, -1.0, top)
    expect += (info.offset - info.decode_offset) / info.scale * (1 + 1j)   # cu8: decoded about 127.4
    assert np.max(np.abs(back.real - expect.real)) <= 0.5 / info.scale + 1e-6
    assert np.max(np.abs(back.imag - expect.imag)) <= 0.5 / info.scale + 1e-6


def test_sigmf_either_file_name_and_project_keys(tmp_path, float_stream):
    with CaptureWriter(tmp_path / "cap", "sigmf", "ci16", 10e6, 490e6, project={"seed": 3}) as writer:
        writer.write(iqformat.encode(float_stream[:100], "ci16"))
    for name in ("cap.sigmf-meta", "cap.sigmf-data"):
        src = open_capture(tmp_path / name)
        assert src.num_samples == 100 and src.sample_rate_hz == 10e6
        assert src.metadata["dtmbnav:seed"] == 3
        assert src.start_utc_unix_ns is None


@settings(max_examples=20, deadline=None)
@given(chunk=st.integers(1, 5000))
def test_reader_output_independent_of_chunk_size(tmp_path_factory, chunk):
    path = tmp_path_factory.mktemp("chunks") / "x.ci8"
    rails = np.arange(2 * 3001, dtype=np.int64).astype(np.int8)
    path.write_bytes(rails.tobytes())
    src = open_capture(path, sample_format="ci8", sample_rate_hz=1e6)
    parts = list(src.chunks(chunk))
    assert all(len(p) == chunk for p in parts[:-1])
    assert np.array_equal(np.concatenate(parts), iqformat.decode(rails, "ci8"))


def test_stdin_stream(monkeypatch):
    rails = np.array([1, 2, 3, 4, 5, 6], np.int8)
    monkeypatch.setattr(sys, "stdin", type("Stdin", (), {"buffer": io.BytesIO(rails.tobytes())})())
    src = open_capture("-", sample_format="ci8", sample_rate_hz=2e6)
    assert src.num_samples is None
    assert np.array_equal(np.concatenate(list(src.chunks(2))), iqformat.decode(rails, "ci8"))


def test_stdin_truncated_and_empty(monkeypatch):
    for data, problem in [(b"\x01\x02\x03", "half an IQ pair"), (b"", "empty")]:
        monkeypatch.setattr(sys, "stdin", type("Stdin", (), {"buffer": io.BytesIO(data)})())
        with pytest.raises(ValueError, match=problem):
            list(open_capture("-", sample_format="ci8", sample_rate_hz=2e6).chunks(10))


def test_bad_sigmf_datatype(tmp_path, make_capture):
    meta = make_capture(tmp_path).meta
    doc = json.loads(meta.read_text())
    doc["global"]["core:datatype"] = "ri8"
    meta.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(str(meta)) + ".*ri8"):
        open_capture(meta)


def test_missing_sigmf_rate(tmp_path, make_capture):
    meta = make_capture(tmp_path).meta
    doc = json.loads(meta.read_text())
    del doc["global"]["core:sample_rate"]
    meta.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(str(meta))):
        open_capture(meta)


def test_truncated_files(tmp_path, make_capture):
    data = make_capture(tmp_path, fmt="ci16").data
    data.write_bytes(data.read_bytes()[:-2])  # half an IQ pair
    with pytest.raises(ValueError, match=re.escape(str(data)) + ".*half an IQ pair"):
        open_capture(data)
    raw = make_capture(tmp_path, "raw", "cu8").data
    raw.write_bytes(raw.read_bytes() + b"\x80")
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*half an IQ pair"):
        open_capture(raw)


def test_empty_and_missing_files(tmp_path, make_capture):
    raw = make_capture(tmp_path, "raw").data
    raw.write_bytes(b"")
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*empty"):
        open_capture(raw)
    with pytest.raises(ValueError, match="nope.ci8"):
        open_capture(tmp_path / "nope.ci8", sample_format="ci8", sample_rate_hz=1e6)
    meta, _, data = make_capture(tmp_path)
    data.unlink()
    with pytest.raises(ValueError, match=re.escape(str(data))):
        open_capture(meta)


def test_nan_in_cf32(tmp_path, make_capture):
    raw = make_capture(tmp_path, "raw", "cf32", n=1000).data
    values = np.zeros(2000, "<f4")
    values[1501] = np.inf
    raw.write_bytes(values.tobytes())
    src = open_capture(raw)
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*NaN or inf"):
        list(src.chunks(256))


def test_inconsistent_and_missing_metadata(tmp_path, make_capture):
    raw, sidecar, _ = make_capture(tmp_path, "raw")
    with pytest.raises(ValueError, match=re.escape(str(sidecar)) + ".*sample rate.*7560000.0.*10000000.0"):
        open_capture(raw, sample_rate_hz=10e6)
    with pytest.raises(ValueError, match="sample format"):
        open_capture(raw, sample_format="ci16")
    (tmp_path / "sigmf").mkdir()
    meta = make_capture(tmp_path / "sigmf").meta
    with pytest.raises(ValueError, match="centre frequency"):
        open_capture(meta, center_hz=490e6)
    sidecar.unlink()
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*sample format and the sample rate"):
        open_capture(raw)
    assert open_capture(raw, sample_format="ci8", sample_rate_hz=7.56e6).num_samples == 10
    sidecar.write_text(json.dumps({"sample_rate_hz": 7.56e6}))
    with pytest.raises(ValueError, match=re.escape(str(sidecar)) + ".*sample_format"):
        open_capture(raw)
    sidecar.write_text(json.dumps({"sample_rate_hz": 7.56e6, "sample_format": "ci12"}))
    with pytest.raises(ValueError, match=re.escape(str(sidecar)) + ".*ci12"):
        open_capture(raw)
    with pytest.raises(ValueError, match="stdin.*sample format"):
        open_capture("-")


class _Trickle(io.RawIOBase):
    """A stream that hands out at most the next of ``sizes`` bytes per read, like a pipe."""

    def __init__(self, data: bytes, sizes: list[int]) -> None:
        self._data, self._sizes, self._at = data, list(sizes), 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        size = min(len(buffer), self._sizes.pop(0) if self._sizes else len(buffer), len(self._data) - self._at)
        buffer[:size] = self._data[self._at:self._at + size]
        self._at += size
        return size


@settings(max_examples=40, deadline=None)
@given(fmt=st.sampled_from(FORMATS), samples=st.integers(1, 300), extra=st.integers(0, 7),
       sizes=st.lists(st.integers(1, 97), max_size=40), chunk=st.integers(1, 64))
def test_stream_yields_what_arrives_and_every_whole_sample(fmt, samples, extra, sizes, chunk):
    """Reads of any size give the same samples; a cut inside a pair yields every whole sample, then says so."""
    info = iqformat.get_format(fmt)
    extra %= info.bytes_per_sample
    rng = np.random.default_rng(samples)
    z = (rng.uniform(-0.9, 0.9, samples) + 1j * rng.uniform(-0.9, 0.9, samples)).astype(np.complex64)
    data = iqformat.encode(z, fmt).tobytes() + bytes(range(1, extra + 1))
    stream = io.BufferedReader(_Trickle(data, sizes), buffer_size=16)
    got = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sys, "stdin", type("Stdin", (), {"buffer": stream})())
        src = open_capture("-", sample_format=fmt, sample_rate_hz=1e6)
        if extra:
            with pytest.raises(TruncatedStream, match="half an IQ pair") as cut:
                for part in src.chunks(chunk):
                    got.append(part)
            assert cut.value.samples == samples
        else:
            got = list(src.chunks(chunk))
    assert all(0 < len(part) <= chunk for part in got)
    assert np.array_equal(np.concatenate(got), iqformat.decode(iqformat.encode(z, fmt).tobytes(), fmt))


@pytest.mark.parametrize("doc, problem", [
    ({"sample_rate_hz": "fast", "sample_format": "ci8"}, "sample_rate_hz must be a number"),
    ({"sample_rate_hz": 0, "sample_format": "ci8"}, "sample_rate_hz must be a finite positive"),
    ({"sample_rate_hz": float("inf"), "sample_format": "ci8"}, "sample_rate_hz must be a finite positive"),
    ({"sample_rate_hz": 1e6, "sample_format": "ci8", "center_hz": "666e6"}, "center_hz must be a number"),
    ({"sample_rate_hz": 1e6, "sample_format": "ci8", "start_utc_unix_ns": 1.5}, "start_utc_unix_ns"),
])
def test_malformed_sidecar_values(tmp_path, make_capture, doc, problem):
    raw, sidecar, _ = make_capture(tmp_path, "raw")
    sidecar.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(str(sidecar)) + ".*" + problem):
        open_capture(raw)


def test_missing_options_are_their_own_error(tmp_path):
    raw = tmp_path / "plain.ci8"
    raw.write_bytes(bytes(8))
    for path in (raw, "-"):
        with pytest.raises(MissingCaptureOptions):
            open_capture(path)


def test_capture_files_and_project_keys(tmp_path, make_capture):
    (tmp_path / "a").mkdir()
    sigmf = make_capture(tmp_path / "a")
    assert set(capture_files(sigmf.data)) == set(capture_files(sigmf.meta)) == {sigmf.meta, sigmf.data}
    raw = make_capture(tmp_path, "raw")
    assert capture_files(raw.capture) == (raw.data, raw.meta)
    assert capture_files("-") == ()
    with CaptureWriter(tmp_path / "sim", "raw", "ci8", 7.56e6, 666e6, project={"scenario": "walk", "seed": 3}) as w:
        w.write(iqformat.encode(np.zeros(4, np.complex64), "ci8"))
    src = open_capture(w.capture_path)
    assert (src.project_value("scenario"), src.project_value("seed"), src.project_value("nope")) == ("walk", 3, None)

"""IQ formats, capture writers and the capture reader: round trips and bad input."""

import io
import json
import re
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dtmbnav.core import iqformat
from dtmbnav.core.records import Track
from receiver.capture import open_capture
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
    lsb = 1.0 / iqformat.get_format(fmt).scale
    tol = 0.5 * lsb + 1e-6 if fmt != "cf32" else 0.0
    assert back.dtype == np.complex64
    assert np.max(np.abs(back.real - z.real)) <= tol
    assert np.max(np.abs(back.imag - z.imag)) <= tol


def test_normalisation_matches_conventions():
    assert iqformat.decode(bytes([128, 0, 255, 192]), "cu8").tolist() == [complex(0, -1), complex(127 / 128, 0.5)]
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


def _sigmf(tmp_path, fmt="ci8", n=10):
    with CaptureWriter(tmp_path / "cap", "sigmf", fmt, 7.56e6, 666e6) as writer:
        writer.write(iqformat.encode(np.zeros(n, np.complex64), fmt))
    return tmp_path / "cap.sigmf-meta", tmp_path / "cap.sigmf-data"


def _raw(tmp_path, fmt="ci8", n=10):
    with CaptureWriter(tmp_path / "cap", "raw", fmt, 7.56e6, 666e6) as writer:
        writer.write(iqformat.encode(np.zeros(n, np.complex64), fmt))
    return writer.capture_path, writer.meta_path


def test_bad_sigmf_datatype(tmp_path):
    meta, _ = _sigmf(tmp_path)
    doc = json.loads(meta.read_text())
    doc["global"]["core:datatype"] = "ri8"
    meta.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(str(meta)) + ".*ri8"):
        open_capture(meta)


def test_missing_sigmf_rate(tmp_path):
    meta, _ = _sigmf(tmp_path)
    doc = json.loads(meta.read_text())
    del doc["global"]["core:sample_rate"]
    meta.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(str(meta))):
        open_capture(meta)


def test_truncated_files(tmp_path):
    _, data = _sigmf(tmp_path, "ci16")
    data.write_bytes(data.read_bytes()[:-2])  # half an IQ pair
    with pytest.raises(ValueError, match=re.escape(str(data)) + ".*half an IQ pair"):
        open_capture(data)
    raw, _ = _raw(tmp_path, "cu8")
    raw.write_bytes(raw.read_bytes() + b"\x80")
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*half an IQ pair"):
        open_capture(raw)


def test_empty_and_missing_files(tmp_path):
    raw, _ = _raw(tmp_path)
    raw.write_bytes(b"")
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*empty"):
        open_capture(raw)
    with pytest.raises(ValueError, match="nope.ci8"):
        open_capture(tmp_path / "nope.ci8", sample_format="ci8", sample_rate_hz=1e6)
    meta, data = _sigmf(tmp_path)
    data.unlink()
    with pytest.raises(ValueError, match=re.escape(str(data))):
        open_capture(meta)


def test_nan_in_cf32(tmp_path):
    raw, _ = _raw(tmp_path, "cf32", n=1000)
    values = np.zeros(2000, "<f4")
    values[1501] = np.inf
    raw.write_bytes(values.tobytes())
    src = open_capture(raw)
    with pytest.raises(ValueError, match=re.escape(str(raw)) + ".*NaN or inf"):
        list(src.chunks(256))


def test_inconsistent_and_missing_metadata(tmp_path):
    raw, sidecar = _raw(tmp_path)
    with pytest.raises(ValueError, match=re.escape(str(sidecar)) + ".*sample rate.*7560000.0.*10000000.0"):
        open_capture(raw, sample_rate_hz=10e6)
    with pytest.raises(ValueError, match="sample format"):
        open_capture(raw, sample_format="ci16")
    (tmp_path / "sigmf").mkdir()
    meta, _ = _sigmf(tmp_path / "sigmf")
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

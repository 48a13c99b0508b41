"""Bad and unusual command lines and files, one case per row: exit code, message, nothing left behind.

Every case runs ``dtmbnav.cli.main`` in-process on small files in its own folder and checks

- the exit code (0 ok, 1 nothing found, 2 usage, 3 bad input, 4 internal error; ``dtmbnav.cli``),
- that stderr names the file or option at fault (and shows no traceback unless ``--debug`` asks),
- that a failure changes nothing in the case's folder: no output at the final path, no hidden
  partial file, and an input named as the output is left as it was (every file is hashed before
  and after). A run that finds nothing (exit 1) may leave only its declared output, without rows.

The inputs are the session's tiny files (``conftest.py``) or copies of them broken one way each.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import TINY_FORMAT, TINY_RATE_HZ, TINY_WALK
from phone_log_samples import gnsslogger_lines, static_log, write_sensor_logger

from dtmbnav import package_version
from dtmbnav.cli import EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_NO_RESULT, EXIT_OK, EXIT_USAGE, main
from dtmbnav_core import schema

RAW_OPTIONS = ["--format", TINY_FORMAT, "--rate", str(TINY_RATE_HZ), "--center", "666e6"]


class Ctx:
    """A case's folder, the session's fixture files (built on first use) and ways to break copies of them."""

    def __init__(self, folder: Path, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch,
                 make_capture) -> None:
        self.tmp = folder
        self.out = folder / "out"
        self.out.mkdir()
        self._request = request
        self.monkeypatch = monkeypatch
        self._make_capture = make_capture
        #: The output a case declares (checked to hold no frames when the exit code is 1).
        self.output: Path | None = None

    def fixture(self, name: str) -> Path:
        return self._request.getfixturevalue(name)

    @property
    def sim(self) -> Path:
        """Folder of the tiny SigMF capture and its ``truth.h5``."""
        return self.fixture("tiny_sim")

    @property
    def rx(self) -> Path:
        return self.fixture("tiny_rx")

    @property
    def truth(self) -> Path:
        """``truth.h5`` of the whole tiny walk."""
        return self.fixture("tiny_walk_truth")

    @property
    def results(self) -> Path:
        return self.fixture("tiny_results")

    def o(self, name: str = "result.h5") -> str:
        """An output path in the case's output folder (declared: see :attr:`output`)."""
        self.output = self.out / name
        return str(self.output)

    def write(self, name: str, data: bytes | str) -> str:
        path = self.tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data if isinstance(data, bytes) else data.encode())
        return str(path)

    def copy(self, src: Path, name: str | None = None) -> str:
        dst = self.tmp / (name or src.name)
        shutil.copy(src, dst)
        return str(dst)

    def h5(self, src: Path, name: str, edit: Callable[[h5py.File], None]) -> str:
        """A copy of an HDF5 file changed by ``edit``."""
        path = self.copy(src, name)
        with h5py.File(path, "a") as f:
            edit(f)
        return path

    def capture(self, container: str = "sigmf", fmt: str = "ci8", n: int = 64, samples=None, folder: str = ""):
        """A small capture ``cap`` in the case's folder or a subfolder of it (``conftest.make_capture``)."""
        where = self.tmp / folder
        where.mkdir(exist_ok=True)
        return self._make_capture(where, container, fmt, n, samples)

    def sigmf_meta(self, edit: Callable[[dict], None]) -> str:
        files = self.capture()
        doc = json.loads(files.meta.read_text())
        edit(doc)
        files.meta.write_text(json.dumps(doc))
        return str(files.meta)

    def sidecar(self, doc: dict | str) -> str:
        files = self.capture("raw")
        files.meta.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        return str(files.capture)

    def stdin(self, data: bytes) -> None:
        self.monkeypatch.setattr(sys, "stdin", type("Stdin", (), {"buffer": io.BytesIO(data)})())

    def tiny_rx_copy(self, name: str = "rx.h5", edit: Callable[[h5py.File], None] | None = None) -> str:
        return self.h5(self.rx, name, edit or (lambda f: None))


@dataclass(frozen=True)
class Case:
    build: Callable[[Ctx], tuple[list[str], list[str]]]
    code: int


CASES: dict[str, Case] = {}


def case(code: int):
    """Register ``build(ctx) -> (argv, words stderr must contain)`` as a case expecting ``code``."""
    def register(build):
        CASES[build.__name__] = Case(build, code)
        return build
    return register


def _drop(group: str, *names: str) -> Callable[[h5py.File], None]:
    """Delete columns of ``group``, or the whole group when no name is given."""
    def edit(f: h5py.File) -> None:
        for path in [f"{group}/{name}" for name in names] or [group]:
            del f[path]
    return edit


def _set_attr(group: str, key: str, value) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        f[group].attrs[key] = value
    return edit


def _replace(group: str, name: str, values: np.ndarray) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        del f[f"{group}/{name}"]
        f[group].create_dataset(name, data=values)
    return edit


# ------------------------------------------------------------------------------------------- the CLI itself

@case(EXIT_USAGE)
def cli_no_subcommand(ctx):
    return [], ["COMMAND"]


@case(EXIT_USAGE)
def cli_unknown_subcommand(ctx):
    return ["frobnicate"], ["frobnicate"]


@case(EXIT_USAGE)
def cli_unknown_option(ctx):
    return ["pdr", str(ctx.sim / "truth.h5"), "-o", ctx.o(), "--bogus"], ["--bogus"]


@case(EXIT_OK)
def cli_version(ctx):
    return ["--version"], []  # printed on stdout: checked in test_version_prints_the_package_version


@case(EXIT_OK)
def cli_quiet_and_debug_after_the_subcommand(ctx):
    return ["pdr", str(ctx.sim / "truth.h5"), "-o", ctx.o("pdr.h5"), "-q", "--debug"], ["steps"]


def _boom(*args, **kwargs):
    raise RuntimeError("boom: a bug")


@case(EXIT_INTERNAL)
def cli_internal_error_is_one_line(ctx):
    ctx.monkeypatch.setattr("dtmbnav.chain.pdr.run_pdr", _boom)
    return ["-q", "pdr", str(ctx.sim / "truth.h5"), "-o", ctx.o()], ["internal error", "RuntimeError", "boom",
                                                                     "--debug"]


@case(EXIT_INTERNAL)
def cli_debug_shows_the_traceback(ctx):
    ctx.monkeypatch.setattr("dtmbnav.chain.pdr.run_pdr", _boom)
    return ["pdr", str(ctx.sim / "truth.h5"), "-o", ctx.o(), "--debug", "-q"], ["Traceback", "_boom",
                                                                               "internal error"]


# ----------------------------------------------------------------------------------------------------- live

def _refused_port() -> int:
    """A local TCP port nothing listens on (bound, then closed)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@case(EXIT_BAD_INPUT)
def live_no_rtl_tcp_server(ctx):
    towers = _towers(ctx, TOWER_ROW)
    url = f"rtl_tcp://127.0.0.1:{_refused_port()}"
    return ["-q", "live", url, "--center", "666e6", "--phone", "sensorlogger:127.0.0.1:0", "--towers", towers,
            "--weinberg-k", "0.5", "--reconnects", "0", "-o", ctx.o("walk")], [url, "rtl_tcp must be running there"]


@case(EXIT_USAGE)
def live_phone_source_unknown(ctx):
    return ["-q", "live", "rtl_tcp://127.0.0.1", "--center", "666e6", "--phone", "bluetooth:phone", "--towers",
            _towers(ctx, TOWER_ROW), "-o", ctx.o("walk")], ["--phone", "sensorlogger:[HOST:]PORT"]


@case(EXIT_USAGE)
def live_not_an_rtl_tcp_url(ctx):
    return ["-q", "live", "walk.cu8", "--center", "666e6", "--phone", "sensorlogger:8000", "--towers",
            _towers(ctx, TOWER_ROW), "-o", ctx.o("walk")], ["walk.cu8", "rtl_tcp://HOST[:PORT]"]


# -------------------------------------------------------------------------------------------------- receive

@case(EXIT_BAD_INPUT)
def receive_empty_file(ctx):
    cap = ctx.write("empty.ci8", b"")
    return ["-q", "receive", cap, *RAW_OPTIONS, "-o", ctx.o()], [cap, "empty"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_data_half_iq_pair(ctx):
    files = ctx.capture(fmt="ci16")
    files.data.write_bytes(files.data.read_bytes()[:-2])  # odd count of int16 rails
    return ["-q", "receive", str(files.meta), "-o", ctx.o()], [str(files.data), "half an IQ pair"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_data_odd_byte_count(ctx):
    files = ctx.capture(fmt="ci16")
    files.data.write_bytes(files.data.read_bytes() + b"\x01")
    return ["-q", "receive", str(files.meta), "-o", ctx.o()], [str(files.data), "half an IQ pair"]


@case(EXIT_BAD_INPUT)
def receive_missing_sigmf_data(ctx):
    files = ctx.capture()
    files.data.unlink()
    return ["-q", "receive", str(files.meta), "-o", ctx.o()], [str(files.data), "not found"]


@case(EXIT_BAD_INPUT)
def receive_missing_sigmf_meta(ctx):
    files = ctx.capture()
    files.meta.unlink()
    return ["-q", "receive", str(files.data), "-o", ctx.o()], [str(files.meta), "not found"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_without_sample_rate(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].pop("core:sample_rate"))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "core:sample_rate"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_without_datatype(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].pop("core:datatype"))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "core:datatype"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_unknown_datatype(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].update({"core:datatype": "ri8"}))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "ri8"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_nan_sample_rate(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].update({"core:sample_rate": float("nan")}))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "core:sample_rate"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_string_frequency(ctx):
    meta = ctx.sigmf_meta(lambda d: d["captures"][0].update({"core:frequency": "666 MHz"}))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta]


@case(EXIT_BAD_INPUT)
def receive_sigmf_malformed_json(ctx):
    files = ctx.capture()
    files.meta.write_text('{"global": {"core:datatype": "ci8",')
    return ["-q", "receive", str(files.meta), "-o", ctx.o()], [str(files.meta), "invalid SigMF metadata"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_malformed_json(ctx):
    cap = ctx.sidecar("{not json")
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "invalid JSON sidecar"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_not_an_object(ctx):
    cap = ctx.sidecar("[1, 2]")
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "expected an object"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_string_rate(ctx):
    cap = ctx.sidecar({"sample_rate_hz": "7.56 Msps", "sample_format": "ci8", "center_hz": 666e6})
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "sample_rate_hz"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_negative_rate(ctx):
    cap = ctx.sidecar({"sample_rate_hz": -7.56e6, "sample_format": "ci8", "center_hz": 666e6})
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "sample_rate_hz"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_nan_rate(ctx):
    cap = ctx.sidecar('{"sample_rate_hz": NaN, "sample_format": "ci8", "center_hz": 666e6}')
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "sample_rate_hz"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_boolean_centre(ctx):
    cap = ctx.sidecar({"sample_rate_hz": 7.56e6, "sample_format": "ci8", "center_hz": True})
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "center_hz"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_bad_start_time(ctx):
    cap = ctx.sidecar({"sample_rate_hz": 7.56e6, "sample_format": "ci8", "start_utc_unix_ns": "yesterday"})
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "start_utc_unix_ns"]


@case(EXIT_BAD_INPUT)
def receive_sidecar_unknown_format(ctx):
    cap = ctx.sidecar({"sample_rate_hz": 7.56e6, "sample_format": "ci12", "center_hz": 666e6})
    return ["-q", "receive", cap, "-o", ctx.o()], [cap + ".json", "ci12"]


@case(EXIT_BAD_INPUT)
def receive_rate_disagrees_with_metadata(ctx):
    cap = str(ctx.capture("raw").capture)
    return ["-q", "receive", cap, "--rate", "10e6", "-o", ctx.o()], [cap + ".json", "sample rate"]


@case(EXIT_USAGE)
def receive_channel_nan(ctx):
    meta = str(ctx.capture().meta)
    return ["-q", "receive", meta, "--channel", "nan", "-o", ctx.o()], ["--channel", "nan"]


@case(EXIT_USAGE)
def receive_channel_outside_the_recorded_band(ctx):
    meta = str(ctx.capture().meta)
    return ["-q", "receive", meta, "--channel", "700e6", "-o", ctx.o()], ["--channel", "outside the recorded band"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_channel_not_a_number(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].update({"dtmbnav:channel_hz": "666 MHz"}))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "dtmbnav:channel_hz"]


@case(EXIT_BAD_INPUT)
def receive_sigmf_channel_outside_the_recorded_band(ctx):
    meta = ctx.sigmf_meta(lambda d: d["global"].update({"dtmbnav:channel_hz": 700e6}))
    return ["-q", "receive", meta, "-o", ctx.o()], [meta, "outside the recorded band"]


@case(EXIT_USAGE)
def receive_raw_without_format_and_rate(ctx):
    cap = ctx.write("plain.ci8", bytes(64))
    return ["-q", "receive", cap, "-o", ctx.o()], [cap, "--format", "--rate"]


@case(EXIT_USAGE)
def receive_raw_without_centre(ctx):
    cap = ctx.write("plain.ci8", bytes(64))
    return ["-q", "receive", cap, "--format", "ci8", "--rate", "7.56e6", "-o", ctx.o()], [cap, "--center"]


@case(EXIT_BAD_INPUT)
def receive_nan_in_cf32(ctx):
    values = np.zeros(2000, "<f4")
    values[1501] = np.nan
    cap = ctx.write("nan.cf32", values.tobytes())
    return ["-q", "receive", cap, "--format", "cf32", "--rate", "7.56e6", "--center", "666e6", "-o", ctx.o()], \
        [cap, "NaN or inf"]


@case(EXIT_BAD_INPUT)
def receive_inf_in_cf32(ctx):
    samples = np.zeros(500, np.complex64)
    files = ctx.capture("raw", "cf32", samples=samples)
    values = np.fromfile(files.data, "<f4")
    values[7] = -np.inf
    values.tofile(files.data)
    return ["-q", "receive", str(files.capture), "-o", ctx.o()], [str(files.data), "NaN or inf"]


@case(EXIT_NO_RESULT)
def receive_noise_only_finds_no_lock(ctx):
    rng = np.random.default_rng(3)
    cap = ctx.write("noise.ci8", np.clip(rng.normal(0, 20, 2 * 400_000), -127, 127).astype(np.int8).tobytes())
    return ["-q", "receive", cap, *RAW_OPTIONS, "-o", ctx.o("rx.h5")], ["no lock"]


@case(EXIT_BAD_INPUT)
def receive_folder_as_capture(ctx):
    folder = ctx.tmp / "capture.ci8"
    folder.mkdir()
    return ["-q", "receive", str(folder), *RAW_OPTIONS, "-o", ctx.o()], [str(folder), "not a file"]


@case(EXIT_BAD_INPUT)
def receive_folder_as_sigmf_data(ctx):
    (ctx.tmp / "cap.sigmf-data").mkdir()
    meta = ctx.write("cap.sigmf-meta", "{}")
    return ["-q", "receive", meta, "-o", ctx.o()], [str(ctx.tmp / "cap.sigmf-data"), "not a file"]


@case(EXIT_BAD_INPUT)
def receive_nonexistent_capture(ctx):
    cap = str(ctx.tmp / "nope.ci8")
    return ["-q", "receive", cap, *RAW_OPTIONS, "-o", ctx.o()], [cap, "no such capture file"]


@case(EXIT_BAD_INPUT)
def receive_output_inside_a_regular_file(ctx):
    blocker = ctx.write("blocker", "a file, not a folder")
    return ["-q", "receive", str(ctx.capture().meta), "-o", blocker + "/rx.h5"], [blocker, "-o", "not a folder"]


@case(EXIT_BAD_INPUT)
def receive_output_folder_missing(ctx):
    out = str(ctx.tmp / "missing" / "rx.h5")
    return ["-q", "receive", str(ctx.capture().meta), "-o", out], [str(ctx.tmp / "missing"), "does not exist"]


@case(EXIT_BAD_INPUT)
def receive_output_is_a_folder(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "-o", str(ctx.out)], [str(ctx.out), "is a folder"]


@case(EXIT_BAD_INPUT)
def receive_csv_inside_a_regular_file(ctx):
    blocker = ctx.write("blocker", "x")
    return ["-q", "receive", str(ctx.capture().meta), "-o", ctx.o(), "--csv", blocker + "/rx.csv"], [blocker,
                                                                                                      "--csv"]


@case(EXIT_USAGE)
def receive_output_is_the_raw_input(ctx):
    cap = str(ctx.capture("raw").capture)
    return ["-q", "receive", cap, "-o", cap], ["-o", cap, "input"]


@case(EXIT_USAGE)
def receive_output_is_the_sigmf_data_file(ctx):
    files = ctx.capture()
    return ["-q", "receive", str(files.meta), "-o", str(files.data)], ["-o", str(files.data), "input"]


@case(EXIT_USAGE)
def receive_output_is_the_sigmf_meta_file(ctx):
    files = ctx.capture()
    return ["-q", "receive", str(files.data), "-o", str(files.meta)], ["-o", str(files.meta), "input"]


@case(EXIT_USAGE)
def receive_csv_is_the_input(ctx):
    cap = str(ctx.capture("raw").capture)
    return ["-q", "receive", cap, "-o", ctx.o(), "--csv", cap], ["--csv", cap, "input"]


@case(EXIT_USAGE)
def receive_csv_is_the_sidecar(ctx):
    files = ctx.capture("raw")
    return ["-q", "receive", str(files.capture), "-o", ctx.o(), "--csv", str(files.meta)], ["--csv", str(files.meta)]


@case(EXIT_USAGE)
def receive_dump_is_the_sigmf_data_file(ctx):
    files = ctx.capture()
    return ["-q", "receive", str(files.meta), "-o", ctx.o(), "--dump", str(files.data)], ["--dump", str(files.data),
                                                                                         "input"]


@case(EXIT_USAGE)
def receive_dump_is_the_output(ctx):
    out = ctx.o()
    return ["-q", "receive", str(ctx.capture().meta), "-o", out, "--dump", out], ["--dump", out]


@case(EXIT_USAGE)
def receive_output_through_another_spelling_of_the_input(ctx):
    files = ctx.capture("raw")
    other = str(ctx.tmp / "." / "out" / ".." / files.capture.name)
    return ["-q", "receive", str(files.capture), "-o", other], ["-o", "input"]


@case(EXIT_USAGE)
def receive_output_and_csv_the_same(ctx):
    out = ctx.o("rx.out")
    return ["-q", "receive", str(ctx.capture().meta), "-o", out, "--csv", out], ["-o", "--csv", out]


@case(EXIT_USAGE)
def receive_hdf5_to_stdout(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "-o", "-"], ["-o -"]


@case(EXIT_USAGE)
def receive_stdin_without_format(ctx):
    ctx.stdin(bytes(64))
    return ["-q", "receive", "-", "--rate", "7.56e6", "-o", ctx.o()], ["stdin", "--format"]


@case(EXIT_BAD_INPUT)
def receive_stdin_empty(ctx):
    ctx.stdin(b"")
    return ["-q", "receive", "-", *RAW_OPTIONS, "-o", ctx.o()], ["-: no samples", "empty"]


@case(EXIT_NO_RESULT)
def receive_stdin_of_three_bytes(ctx):
    ctx.stdin(b"\x01\x02\x03")  # one ci8 sample and half of the next
    return ["-q", "receive", "-", *RAW_OPTIONS, "-o", ctx.o("rx.h5")], ["no lock", "ended early",
                                                                       "inside an IQ pair"]


@case(EXIT_USAGE)
def receive_rate_zero(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--rate", "0", "-o", ctx.o()], ["--rate", "positive"]


@case(EXIT_USAGE)
def receive_rate_nan(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--rate", "nan", "-o", ctx.o()], ["--rate", "finite"]


@case(EXIT_USAGE)
def receive_rate_text(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--rate", "fast", "-o", ctx.o()], ["--rate", "'fast'"]


@case(EXIT_USAGE)
def receive_rate_negative(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--rate=-7.56e6", "-o", ctx.o()], ["--rate", "positive"]


@case(EXIT_USAGE)
def receive_centre_inf(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--center", "inf", "-o", ctx.o()], ["--center", "finite"]


@case(EXIT_USAGE)
def receive_clock_offset_nan(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--clock-offset", "nan", "-o", ctx.o()], ["--clock-offset"]


@case(EXIT_USAGE)
def receive_clock_offset_inf(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--clock-offset=-inf", "-o", ctx.o()], ["--clock-offset",
                                                                                              "finite"]


@case(EXIT_USAGE)
def receive_static_window_zero_without_clock_offset(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--static-window", "0", "-o", ctx.o()], ["--static-window",
                                                                                              "--clock-offset"]


@case(EXIT_USAGE)
def receive_static_window_negative(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--static-window=-1", "-o", ctx.o()], ["--static-window"]


@case(EXIT_USAGE)
def receive_unknown_format(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--format", "ci12", "-o", ctx.o()], ["--format", "ci12"]


@case(EXIT_USAGE)
def receive_unknown_pn_mode(ctx):
    return ["-q", "receive", str(ctx.capture().meta), "--pn-mode", "PN999", "-o", ctx.o()], ["--pn-mode"]


# ------------------------------------------------------------------------------------------------------ pdr

@case(EXIT_BAD_INPUT)
def pdr_nonexistent_sensors(ctx):
    path = str(ctx.tmp / "nope.h5")
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "no such file"]


@case(EXIT_BAD_INPUT)
def pdr_folder_as_sensors(ctx):
    return ["-q", "pdr", str(ctx.out), "-o", ctx.o()], [str(ctx.out), "not a file"]


@case(EXIT_BAD_INPUT)
def pdr_sensors_not_hdf5(ctx):
    path = ctx.write("sensors.h5", "t,acc\n0,9.81\n")
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "not a readable HDF5 file"]


@case(EXIT_BAD_INPUT)
def pdr_sensors_empty_file(ctx):
    path = ctx.write("sensors.h5", b"")
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "HDF5"]


@case(EXIT_BAD_INPUT)
def pdr_sensors_without_imu(ctx):
    path = ctx.h5(ctx.truth, "sensors.h5", _drop(schema.IMU))
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "/imu"]


@case(EXIT_BAD_INPUT)
def pdr_imu_wrong_shape(ctx):
    path = ctx.h5(ctx.truth, "sensors.h5", _replace(schema.IMU, "acc_mps2", np.zeros((10, 2))))
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "acc_mps2"]


@case(EXIT_BAD_INPUT)
def pdr_imu_missing_column(ctx):
    path = ctx.h5(ctx.truth, "sensors.h5", _drop(schema.IMU, "gyro_radps"))
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "gyro_radps"]


@case(EXIT_BAD_INPUT)
def pdr_imu_with_nan(ctx):
    def edit(f):
        f["imu/acc_mps2"][5, 1] = np.nan
    path = ctx.h5(ctx.truth, "sensors.h5", edit)
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "acc_mps2", "NaN"]


@case(EXIT_BAD_INPUT)
def pdr_imu_time_going_back(ctx):
    def edit(f):
        f["imu/t_s"][10] = 0.0
    path = ctx.h5(ctx.truth, "sensors.h5", edit)
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "t_s", "increasing"]


@case(EXIT_BAD_INPUT)
def pdr_incomplete_file(ctx):
    path = ctx.h5(ctx.truth, "sensors.h5", lambda f: f.attrs.__setitem__(schema.COMPLETE_ATTR, False))
    return ["-q", "pdr", path, "-o", ctx.o()], [path, "incomplete"]


@case(EXIT_BAD_INPUT)
def pdr_malformed_weinberg_attribute(ctx):
    path = ctx.h5(ctx.truth, "sensors.h5", _set_attr(schema.IMU, schema.WEINBERG_K_ATTR, "tall"))
    return ["-q", "pdr", path, "-o", ctx.o()], [path, schema.WEINBERG_K_ATTR]


@case(EXIT_USAGE)
def pdr_output_is_the_input(ctx):
    path = ctx.copy(ctx.truth, "sensors.h5")
    return ["-q", "pdr", path, "-o", path], ["-o", path, "input"]


@case(EXIT_USAGE)
def pdr_csv_is_the_input(ctx):
    path = ctx.copy(ctx.truth, "sensors.h5")
    return ["-q", "pdr", path, "-o", ctx.o(), "--csv", path], ["--csv", path, "input"]


@case(EXIT_USAGE)
def pdr_weinberg_k_zero(ctx):
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--weinberg-k", "0"], ["--weinberg-k"]


@case(EXIT_USAGE)
def pdr_unknown_step_model(ctx):
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--step-model", "giant"], ["--step-model"]


def _calibrate(ctx, sensors: str | Path, *extra: str, out: str = "walker.toml") -> list[str]:
    return ["-q", "pdr", str(sensors), "--calibrate", "-o", ctx.o(out), *extra]


@case(EXIT_USAGE)
def pdr_calibrate_without_distance(ctx):
    return _calibrate(ctx, ctx.truth), ["--calibrate needs --distance"]


@case(EXIT_USAGE)
def pdr_distance_without_calibrate(ctx):
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--distance", "50"], ["--distance goes with --calibrate"]


@case(EXIT_USAGE)
def pdr_calibrate_distance_zero(ctx):
    return _calibrate(ctx, ctx.truth, "--distance", "0"), ["--distance", "positive"]


@case(EXIT_USAGE)
def pdr_calibrate_distance_negative(ctx):
    return _calibrate(ctx, ctx.truth, "--distance=-5"), ["--distance", "positive"]


@case(EXIT_USAGE)
def pdr_calibrate_to_an_hdf5_name(ctx):
    return _calibrate(ctx, ctx.truth, "--distance", "50", out="walker.h5"), ["walker.h5", "*.toml"]


@case(EXIT_USAGE)
def pdr_calibrate_with_a_given_gain(ctx):
    return _calibrate(ctx, ctx.truth, "--distance", "50", "--weinberg-k", "0.4"), ["drop --weinberg-k"]


@case(EXIT_BAD_INPUT)
def pdr_calibrate_walk_without_steps(ctx):
    """A phone lying still: no steps to fit the gain to; nothing written."""
    def still(f):
        f["imu/acc_mps2"][...] = [0.0, 0.0, 9.81]
        f["imu/gyro_radps"][...] = 0.0
    path = ctx.h5(ctx.truth, "sensors.h5", still)
    return _calibrate(ctx, path, "--distance", "50"), [path, "no steps detected"]


@case(EXIT_BAD_INPUT)
def pdr_calibrate_nonexistent_sensors(ctx):
    path = str(ctx.tmp / "nope.h5")
    return _calibrate(ctx, path, "--distance", "50"), [path, "no such file"]


@case(EXIT_BAD_INPUT)
def pdr_walker_profile_missing(ctx):
    walker = str(ctx.tmp / "walker.toml")
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker], [walker, "no such walker profile",
                                                                             "--calibrate"]


@case(EXIT_BAD_INPUT)
def pdr_walker_profile_not_toml(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = = 0.4\n")
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker], [walker, "not a TOML", "line 1"]


@case(EXIT_BAD_INPUT)
def pdr_walker_profile_without_gain(ctx):
    walker = ctx.write("walker.toml", "[calibration]\ndistance_m = 50.0\n")
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker], [walker, "no weinberg_k_m"]


@case(EXIT_BAD_INPUT)
def pdr_walker_profile_negative_gain(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = -0.4\n")
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker], [walker, "weinberg_k_m", "positive"]


@case(EXIT_BAD_INPUT)
def pdr_walker_profile_text_gain_by_carriage(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = 0.4\n[weinberg_k_m_by_carriage]\nhandheld = \"tall\"\n")
    return ["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker], [walker, "handheld", "'tall'"]


@case(EXIT_USAGE)
def pdr_walker_and_weinberg_k(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = 0.4\n")
    return (["-q", "pdr", str(ctx.truth), "-o", ctx.o(), "--walker", walker, "--weinberg-k", "0.45"],
            ["--weinberg-k and --walker", "give one"])


@case(EXIT_USAGE)
def fuse_walker_and_weinberg_k(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = 0.4\n")
    return (_fuse(ctx, ctx.rx, ctx.sim / "truth.h5") + ["--walker", walker, "--weinberg-k", "0.45"],
            ["--weinberg-k and --walker", "give one"])


@case(EXIT_BAD_INPUT)
def fuse_walker_profile_missing(ctx):
    walker = str(ctx.tmp / "walker.toml")
    return _fuse(ctx, ctx.rx, ctx.sim / "truth.h5") + ["--walker", walker], [walker, "no such walker profile"]


@case(EXIT_USAGE)
def pdr_calibrate_over_the_walker_profile(ctx):
    walker = ctx.write("walker.toml", "weinberg_k_m = 0.4\n")
    return (["-q", "pdr", str(ctx.truth), "--calibrate", "--distance", "50", "-o", walker, "--walker", walker],
            ["drop --walker"])


# -------------------------------------------------------------------------------------------------- sensors

def _static_lines() -> list[str]:
    """A GnssLogger log of a phone lying still (``phone_log_samples.static_log``), one provider's fixes."""
    return gnsslogger_lines(*static_log(), flp=False)


def _first(lines: list[str], prefix: str, after: int = 0) -> int:
    """Index of the first line starting with ``prefix`` after index ``after``."""
    return next(i for i, line in enumerate(lines) if i >= after and line.startswith(prefix))


def _gnss_log(ctx, lines: list[str], end: str = "\n") -> str:
    return ctx.write("gnss_log.txt", "\n".join(lines) + end)


def _log_with_field(ctx, prefix: str, field: int, value: str) -> tuple[str, str]:
    """The static log with one field of its first row starting with ``prefix`` set: its path, and ``path:line``."""
    lines = _static_lines()
    i = _first(lines, prefix)
    fields = lines[i].split(",")
    fields[field] = value
    lines[i] = ",".join(fields)
    log = _gnss_log(ctx, lines)
    return log, f"{log}:{i + 1}"


def _sensors(ctx, *logs: str, extra: tuple[str, ...] = ()) -> list[str]:
    return ["-q", "sensors", *logs, "-o", ctx.o("sensors.h5"), *extra]


def _export(ctx, *drop: str) -> Path:
    """A Sensor Logger export of the still phone in ``export/``, without the files ``drop``."""
    folder = write_sensor_logger(ctx.tmp / "export", *static_log())
    for name in drop:
        (folder / name).unlink()
    return folder


@case(EXIT_BAD_INPUT)
def sensors_empty_log(ctx):
    log = ctx.write("gnss_log.txt", "")
    return _sensors(ctx, log), [log, "empty file"]


@case(EXIT_BAD_INPUT)
def sensors_log_of_blank_lines(ctx):
    log = ctx.write("gnss_log.txt", "\n \r\n\n")
    return _sensors(ctx, log), [log, "empty file"]


@case(EXIT_BAD_INPUT)
def sensors_truncated_last_row(ctx):
    lines = _static_lines()
    row = lines[_first(lines, "UncalAccel,")]
    lines.append(row[:len(row) // 2])
    log = _gnss_log(ctx, lines, end="")
    return _sensors(ctx, log), [f"{log}:{len(lines)}", "truncated", "ends inside it"]


@case(EXIT_BAD_INPUT)
def sensors_row_with_an_extra_field(ctx):
    lines = _static_lines()
    i = _first(lines, "Gyro,")
    lines[i] += ",0.5"
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [f"{log}:{i + 1}", "Gyro row has 7 fields", "header (line"]


@case(EXIT_BAD_INPUT)
def sensors_fix_row_missing_a_field(ctx):
    lines = _static_lines()
    i = _first(lines, "Fix,")
    lines[i] = lines[i].rsplit(",", 1)[0]
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [f"{log}:{i + 1}", "Fix row has 13 fields"]


@case(EXIT_BAD_INPUT)
def sensors_unknown_format(ctx):
    log = ctx.write("track.txt", "latitude;longitude\n30.5;114.3\n")
    return _sensors(ctx, log), [log, "unknown format", "GnssLogger", "Sensor Logger"]


@case(EXIT_BAD_INPUT)
def sensors_binary_log(ctx):
    log = ctx.write("gnss_log.txt", b"\x89PNG\r\n\x1a\n\xff\x00\x00")
    return _sensors(ctx, log), [log, "not a text log"]


@case(EXIT_BAD_INPUT)
def sensors_log_without_imu_rows(ctx):
    lines = [line for line in _static_lines() if not line.startswith(("UncalAccel,", "Gyro,", "UncalMag,"))]
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [log, "no accelerometer rows", "UncalAccel"]


@case(EXIT_BAD_INPUT)
def sensors_log_without_gyro(ctx):
    log = _gnss_log(ctx, [line for line in _static_lines() if not line.startswith("Gyro,")])
    return _sensors(ctx, log), [log, "no gyroscope rows"]


@case(EXIT_BAD_INPUT)
def sensors_time_going_back(ctx):
    lines = _static_lines()
    a = _first(lines, "UncalAccel,")
    b = _first(lines, "UncalAccel,", a + 1)
    lines[a], lines[b] = lines[b], lines[a]
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [f"{log}:{b + 1}", "time goes back"]


@case(EXIT_BAD_INPUT)
def sensors_nan_value(ctx):
    log, where = _log_with_field(ctx, "UncalAccel,", 4, "NaN")
    return _sensors(ctx, log), [where, "UncalAccelYMps2", "NaN"]


@case(EXIT_BAD_INPUT)
def sensors_empty_value(ctx):
    log, where = _log_with_field(ctx, "Gyro,", 3, "")
    return _sensors(ctx, log), [where, "GyroXRadPerSec is empty"]


@case(EXIT_BAD_INPUT)
def sensors_text_timestamp(ctx):
    log, where = _log_with_field(ctx, "UncalMag,", 2, "soon")
    return _sensors(ctx, log), [where, "elapsedRealtimeNanos", "'soon'"]


@case(EXIT_OK)
def sensors_log_without_fix_rows_gives_imu_and_a_warning(ctx):
    log = _gnss_log(ctx, [line for line in _static_lines() if not line.startswith("Fix,")])
    return _sensors(ctx, log)[1:], [log, "no Fix rows", "--start X,Y"]


@case(EXIT_OK)
def sensors_sensor_logger_empty_location_gives_imu_and_a_warning(ctx):
    folder = _export(ctx)
    (folder / "Location.csv").write_text("")
    return _sensors(ctx, str(folder))[1:], ["Location.csv", "no fixes", "--start X,Y"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_far_slower_than_the_grid(ctx):
    log = _gnss_log(ctx, gnsslogger_lines(*static_log(seconds=4.0, rate_hz=2.0), flp=False))
    return _sensors(ctx, log), [log, "accelerometer sampled at 2 Hz", "8 samples", "below the 20 Hz"]


@case(EXIT_BAD_INPUT)
def sensors_accel_rows_without_utc_time(ctx):
    """An accelerometer header without utcTimeMillis: no tie between the UTC clock and the sensors' clock."""
    lines = [line.replace("# UncalAccel,utcTimeMillis,", "# UncalAccel,") if line.startswith("# UncalAccel,")
             else ",".join(line.split(",")[:1] + line.split(",")[2:]) if line.startswith("UncalAccel,") else line
             for line in _static_lines()]
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [log, "has no utcTimeMillis", "UTC clock"]


@case(EXIT_BAD_INPUT)
def sensors_latitude_out_of_range(ctx):
    log, where = _log_with_field(ctx, "Fix,", 2, "91.5")
    return _sensors(ctx, log), [where, "latitude 91.5", "out of range"]


@case(EXIT_BAD_INPUT)
def sensors_longitude_out_of_range(ctx):
    log, where = _log_with_field(ctx, "Fix,", 3, "-190.0")
    return _sensors(ctx, log), [where, "longitude -190", "out of range"]


@case(EXIT_BAD_INPUT)
def sensors_row_before_its_header(ctx):
    log = _gnss_log(ctx, [line for line in _static_lines() if not line.startswith("# Gyro,")])
    return _sensors(ctx, log), [log, "before any '# Gyro,...' header line"]


@case(EXIT_BAD_INPUT)
def sensors_fixes_without_accuracy(ctx):
    lines = _static_lines()
    for i, line in enumerate(lines):
        if line.startswith("Fix,"):
            fields = line.split(",")
            fields[6] = ""
            lines[i] = ",".join(fields)
    log = _gnss_log(ctx, lines)
    return _sensors(ctx, log), [log, "no fix states its horizontal accuracy"]


@case(EXIT_BAD_INPUT)
def sensors_two_gnsslogger_logs(ctx):
    a = ctx.write("a.txt", "\n".join(_static_lines()) + "\n")
    b = ctx.write("b.txt", "\n".join(_static_lines()) + "\n")
    return _sensors(ctx, a, b), [a, "give it alone"]


@case(EXIT_BAD_INPUT)
def sensors_nonexistent_log(ctx):
    log = str(ctx.tmp / "gnss_log.txt")
    return _sensors(ctx, log), [log, "no such file"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_folder_without_accelerometer(ctx):
    folder = str(_export(ctx, "Accelerometer.csv", "TotalAcceleration.csv"))
    return _sensors(ctx, folder), [folder, "no Accelerometer.csv"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_acceleration_without_gravity(ctx):
    folder = _export(ctx, "TotalAcceleration.csv")
    return _sensors(ctx, str(folder)), [str(folder / "Accelerometer.csv"), "without gravity", "TotalAcceleration.csv"]


def _ios_export(ctx, mag: bool = True, latitude_deg: float | None = None) -> Path:
    """An iPhone's export of the still phone (gravity split, iOS's sign) without Metadata.csv; without the
    magnetometer unless ``mag``, its fixes at ``latitude_deg`` where given."""
    acc, gyro, field, fixes = static_log()
    if latitude_deg is not None:
        fixes = replace(fixes, lat_deg=np.full(len(fixes.t_s), latitude_deg))
    folder = write_sensor_logger(ctx.tmp / "export", acc, gyro, field if mag else None, fixes, gravity_split=True,
                                 ios=True)
    (folder / "Metadata.csv").unlink()
    return folder


@case(EXIT_OK)
def sensors_sensor_logger_ios_without_metadata_is_told_by_the_dip(ctx):
    """Without Metadata.csv nor TotalAcceleration.csv the Earth's field's dip against gravity (north of the
    equator) says iOS's sign, and the user is told."""
    folder = str(_ios_export(ctx))
    return _sensors(ctx, folder)[1:], [folder, "dip against gravity", "ios's sign"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_without_metadata_near_the_equator(ctx):
    """Near the equator the field may dip either way: the data cannot say the sign, so the user must."""
    folder = str(_ios_export(ctx, latitude_deg=5.0))
    return _sensors(ctx, folder), [folder, "no platform (Metadata.csv)", "equator", "--platform android"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_without_metadata_nor_magnetometer(ctx):
    folder = str(_ios_export(ctx, mag=False))
    return _sensors(ctx, folder), [folder, "no magnetometer", "--platform"]


@case(EXIT_OK)
def sensors_sensor_logger_platform_stands_in_for_metadata(ctx):
    folder = str(_ios_export(ctx, mag=False))
    return _sensors(ctx, folder, extra=("--platform", "ios"))[1:], ["iOS acceleration frame"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_platform_disagrees_with_metadata(ctx):
    folder = str(_export(ctx))
    return _sensors(ctx, folder, extra=("--platform", "ios")), [folder, "--platform ios", "Metadata.csv",
                                                                "--platform android"]


@case(EXIT_BAD_INPUT)
def sensors_gnsslogger_log_with_platform_ios(ctx):
    log = ctx.write("gnss_log.txt", "\n".join(_static_lines()) + "\n")
    return _sensors(ctx, log, extra=("--platform", "ios")), [log, "GnssLogger", "--platform ios"]


@case(EXIT_USAGE)
def sensors_unknown_platform(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--platform", "windows")), ["--platform", "windows"]


@case(EXIT_OK)
def sensors_sensor_logger_without_metadata_with_total_acceleration_is_android(ctx):
    folder = _export(ctx, "Metadata.csv")
    return _sensors(ctx, str(folder))[1:], [str(folder)]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_without_gyroscope(ctx):
    folder = str(_export(ctx, "Gyroscope.csv"))
    return _sensors(ctx, folder), [folder, "no Gyroscope.csv"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_without_location(ctx):
    folder = str(_export(ctx, "Location.csv"))
    return _sensors(ctx, folder), [folder, "no Location.csv"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_nan_sample(ctx):
    path = _export(ctx) / "Gyroscope.csv"
    lines = path.read_text().splitlines()
    lines[3] = ",".join(lines[3].split(",")[:2] + ["nan", "0.0", "0.0"])
    path.write_text("\n".join(lines) + "\n")
    return _sensors(ctx, str(path.parent)), [f"{path}:4", "z is nan", "NaN"]


@case(EXIT_BAD_INPUT)
def sensors_sensor_logger_latitude_out_of_range(ctx):
    path = _export(ctx) / "Location.csv"
    lines = path.read_text().splitlines()
    lines[1] = lines[1].rsplit(",", 1)[0] + ",-95.0"
    path.write_text("\n".join(lines) + "\n")
    return _sensors(ctx, str(path.parent)), [f"{path}:2", "latitude -95", "out of range"]


@case(EXIT_OK)
def sensors_repeated_timestamp_is_dropped_with_a_warning(ctx):
    lines = _static_lines()
    i = _first(lines, "Gyro,")
    lines.insert(i + 1, lines[i])
    log = _gnss_log(ctx, lines)
    return ["sensors", log, "-o", ctx.o("sensors.h5")], ["warning", "repeated timestamp dropped", f"line {i + 2})"]


@case(EXIT_USAGE)
def sensors_origin_one_number(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--origin", "30.5")), ["--origin", "LAT,LON"]


@case(EXIT_USAGE)
def sensors_origin_text(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--origin", "north,east")), ["--origin", "numbers"]


@case(EXIT_USAGE)
def sensors_origin_latitude_out_of_range(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--origin", "95,114")), ["--origin", "out of range"]


@case(EXIT_USAGE)
def sensors_origin_nan(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--origin", "nan,114,3")), ["--origin", "finite"]


@case(EXIT_USAGE)
def sensors_rate_zero(ctx):
    return _sensors(ctx, str(ctx.tmp / "gnss_log.txt"), extra=("--rate", "0")), ["--rate"]


@case(EXIT_USAGE)
def sensors_output_is_the_log(ctx):
    log = _gnss_log(ctx, _static_lines())
    return ["-q", "sensors", log, "-o", log], ["-o", log, "LOG"]


@case(EXIT_USAGE)
def sensors_hdf5_to_stdout(ctx):
    log = _gnss_log(ctx, _static_lines())
    return ["-q", "sensors", log, "-o", "-"], ["-o -"]


# ----------------------------------------------------------------------------------------------------- fuse

def _fuse(ctx, receiver: str | Path, sensors: str | Path, *extra: str) -> list[str]:
    return ["-q", "fuse", "--receiver", str(receiver), "--sensors", str(sensors), "-o", ctx.o(), *extra]


@case(EXIT_BAD_INPUT)
def fuse_receiver_without_frames_group(ctx):
    rx = ctx.tiny_rx_copy(edit=_drop("receiver"))
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "/receiver/frames"]


@case(EXIT_BAD_INPUT)
def fuse_receiver_missing_a_column(ctx):
    rx = ctx.tiny_rx_copy(edit=_drop(schema.RECEIVER_FRAMES, "range_change_m"))
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "range_change_m"]


@case(EXIT_BAD_INPUT)
def fuse_receiver_columns_of_different_lengths(ctx):
    rx = ctx.tiny_rx_copy(edit=_replace(schema.RECEIVER_FRAMES, "snr_db", np.zeros(3, np.float32)))
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "differ in length"]


@case(EXIT_BAD_INPUT)
def fuse_receiver_text_column(ctx):
    rx = ctx.tiny_rx_copy(edit=_replace(schema.RECEIVER_FRAMES, "flags", np.array([b"x"] * 719)))
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "flags", "numeric"]


@case(EXIT_BAD_INPUT)
def fuse_receiver_with_no_frames(ctx):
    def edit(f):
        for name in list(f[schema.RECEIVER_FRAMES]):
            f[schema.RECEIVER_FRAMES][name].resize((0,))
    rx = ctx.tiny_rx_copy(edit=edit)
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "no frames"]


@case(EXIT_BAD_INPUT)
def fuse_receiver_incomplete(ctx):
    rx = ctx.tiny_rx_copy(edit=lambda f: f.attrs.__setitem__(schema.COMPLETE_ATTR, False))
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "incomplete"]


@case(EXIT_BAD_INPUT)
def fuse_sensors_without_imu(ctx):
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", _drop(schema.IMU))
    return _fuse(ctx, ctx.rx, sensors), [sensors, "/imu"]


@case(EXIT_BAD_INPUT)
def fuse_gnss_without_start_fix(ctx):
    def edit(f):
        for key in schema.START_FIX_ATTRS:
            del f[schema.GNSS].attrs[key]
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", edit)
    return _fuse(ctx, ctx.rx, sensors), [sensors, "/gnss", "start-fix"]


@case(EXIT_USAGE)
def fuse_sensors_without_fixes_needs_start(ctx):
    """A sensors file of a phone log without fixes: /gnss without rows and without a start fix."""
    def edit(f):
        for name in list(f[schema.GNSS]):
            del f[schema.GNSS][name]
            f[schema.GNSS].create_dataset(name, data=np.zeros(0))
        for key in schema.START_FIX_ATTRS:
            del f[schema.GNSS].attrs[key]
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", edit)
    return _fuse(ctx, ctx.rx, sensors), [sensors, "no fixes", "--start X,Y"]


@case(EXIT_BAD_INPUT)
def fuse_gnss_malformed_start_fix(ctx):
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", _set_attr(schema.GNSS, "start_fix_x_m", "north"))
    return _fuse(ctx, ctx.rx, sensors), [sensors, "start-fix"]


@case(EXIT_BAD_INPUT)
def fuse_sensors_without_tower(ctx):
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", _drop(schema.TRUTH_TRAJECTORY))
    return _fuse(ctx, ctx.rx, sensors), [sensors, "--tower"]


@case(EXIT_BAD_INPUT)
def fuse_files_of_different_scenarios(ctx):
    assert main(["-q", "simulate", "park-loop", "--no-iq", "-o", str(ctx.tmp / "park")]) == EXIT_OK
    sensors = ctx.tmp / "park" / "truth.h5"
    return _fuse(ctx, ctx.rx, sensors), [str(ctx.rx), str(sensors), "different walks", "park-loop-cw"]


@case(EXIT_BAD_INPUT)
def fuse_files_of_different_seeds(ctx):
    sensors = ctx.h5(ctx.sim / "truth.h5", "sensors.h5", _set_attr(schema.TRUTH_FRAMES, "seed", 8))
    return _fuse(ctx, ctx.rx, sensors), [sensors, "different walks", "seed"]


@case(EXIT_BAD_INPUT)
def fuse_files_that_do_not_overlap_in_time(ctx):
    def edit(f):
        f[schema.RECEIVER_FRAMES]["t_s"][...] += 1000.0
        for key in (schema.CAPTURE_SCENARIO_ATTR, schema.CAPTURE_SEED_ATTR):
            del f[schema.RECEIVER_FRAMES].attrs[key]
    rx = ctx.tiny_rx_copy(edit=edit)
    return _fuse(ctx, rx, ctx.sim / "truth.h5"), [rx, "do not overlap"]


@case(EXIT_USAGE)
def fuse_particles_zero(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--particles", "0"), ["--particles"]


@case(EXIT_USAGE)
def fuse_particles_negative(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--particles", "-1"), ["--particles"]


@case(EXIT_USAGE)
def fuse_particles_text(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--particles", "x"), ["--particles", "'x'"]


@case(EXIT_USAGE)
def fuse_filters_bogus(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--filters", "pf,kalman"), ["--filters", "kalman"]


@case(EXIT_USAGE)
def fuse_filters_empty(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--filters", ""), ["--filters"]


@case(EXIT_USAGE)
def fuse_filters_only_commas(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--filters", ",,"), ["--filters"]


@case(EXIT_USAGE)
def fuse_tower_one_number(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower", "2000"), ["--tower", "X,Y"]


@case(EXIT_USAGE)
def fuse_tower_three_numbers(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower", "1,2,3"), ["--tower"]


@case(EXIT_USAGE)
def fuse_tower_nan(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower", "nan,2200"), ["--tower", "finite"]


@case(EXIT_BAD_INPUT)
def fuse_tower_ll_without_a_geodetic_origin(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower-ll", "30.5,114.3"), [str(ctx.truth), "no geodetic origin",
                                                                        "--tower X,Y"]


@case(EXIT_USAGE)
def fuse_tower_and_tower_ll(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower", "1,2", "--tower-ll", "30.5,114.3"), ["--tower-ll",
                                                                                           "not allowed with"]


@case(EXIT_USAGE)
def fuse_tower_ll_longitude_out_of_range(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower-ll", "30.5,200"), ["--tower-ll", "out of range"]


#: The header the simulator writes a towers CSV with, and a valid row of it.
TOWERS_HEADER = "name,lat_deg,lon_deg,height_m,channel_hz,transmit_delay_s"
TOWER_ROW = "Guishan,30.5508,114.2763,420,,"


def _towers(ctx, *rows: str, header: str = TOWERS_HEADER, name: str = "towers.csv") -> str:
    """A towers file in the case's folder: ``header`` and ``rows`` as lines."""
    return ctx.write(name, "".join(f"{line}\n" for line in (header, *rows)))


@case(EXIT_BAD_INPUT)
def fuse_towers_without_the_named_tower(ctx):
    towers = _towers(ctx, TOWER_ROW, "Hongshan,30.5071,114.3382,96.5,,2.5e-6")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers, "--tower-name", "Wuchang"), [
        towers, "no tower named 'Wuchang'", "'Guishan', 'Hongshan'"]


@case(EXIT_BAD_INPUT)
def fuse_towers_latitude_91(ctx):
    towers = _towers(ctx, "Guishan,91,114.2763,420,,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 2", "lat_deg 91 deg is out of range"]


@case(EXIT_BAD_INPUT)
def fuse_towers_longitude_minus_181(ctx):
    towers = _towers(ctx, TOWER_ROW, "Hongshan,30.5071,-181,96.5,,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 3", "lon_deg -181 deg is out of range"]


@case(EXIT_BAD_INPUT)
def fuse_towers_without_a_lat_column(ctx):
    towers = _towers(ctx, "Guishan,114.2763,420", header="name,lon_deg,height_m")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 1", "no column(s) lat_deg"]


@case(EXIT_BAD_INPUT)
def fuse_towers_height_not_a_number(ctx):
    towers = _towers(ctx, "Guishan,30.5508,114.2763,tall,,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 2", "height_m must be a number", "'tall'"]


@case(EXIT_BAD_INPUT)
def fuse_towers_height_absurd(ctx):
    towers = _towers(ctx, "Guishan,30.5508,114.2763,42000,,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 2", "height_m 42000 m is out of range"]


@case(EXIT_BAD_INPUT)
def fuse_towers_duplicate_names(ctx):
    towers = _towers(ctx, TOWER_ROW, "Hongshan,30.5071,114.3382,96.5,,", TOWER_ROW)
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "'Guishan' given more than once"]


@case(EXIT_BAD_INPUT)
def fuse_towers_empty_file(ctx):
    towers = ctx.write("towers.csv", "")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "empty", "header row"]


@case(EXIT_BAD_INPUT)
def fuse_towers_header_only(ctx):
    towers = _towers(ctx)
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "no towers"]


@case(EXIT_BAD_INPUT)
def fuse_towers_toml_without_towers_tables(ctx):
    towers = ctx.write("towers.toml", '[[tower]]\nname = "Guishan"\nlat_deg = 30.5\nlon_deg = 114.3\nheight_m = 420\n')
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "no [[towers]] table"]


@case(EXIT_BAD_INPUT)
def fuse_towers_toml_entry_missing_a_field(ctx):
    towers = ctx.write("towers.toml", '[[towers]]\nname = "Guishan"\nlat_deg = 30.5\nlon_deg = 114.3\n')
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "[[towers]] entry 1", "missing height_m"]


@case(EXIT_BAD_INPUT)
def fuse_towers_nan(ctx):
    towers = _towers(ctx, "Guishan,nan,114.2763,420,,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "line 2", "lat_deg must be a finite number"]


@case(EXIT_BAD_INPUT)
def fuse_towers_nonexistent_file(ctx):
    towers = str(ctx.tmp / "towers.csv")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, "no such file"]


@case(EXIT_BAD_INPUT)
def fuse_towers_of_an_unknown_format(ctx):
    towers = _towers(ctx, TOWER_ROW, name="towers.txt")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [towers, ".toml", ".csv"]


@case(EXIT_BAD_INPUT)
def fuse_towers_named_tower_on_another_channel(ctx):
    towers = _towers(ctx, "Guishan,30.5508,114.2763,420,730e6,")
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers, "--tower-name", "Guishan"), [
        towers, "'Guishan' (7.3e+08 Hz)", "another channel"]


@case(EXIT_BAD_INPUT)
def fuse_towers_without_a_geodetic_origin(ctx):
    towers = _towers(ctx, TOWER_ROW)
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers), [str(ctx.truth), "no geodetic origin"]


@case(EXIT_USAGE)
def fuse_towers_and_tower(ctx):
    towers = _towers(ctx, TOWER_ROW)
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower", "1,2", "--towers", towers), ["--towers", "not allowed with"]


def _field_pair(ctx, capture_utc_ns: int, log_utc_ns: int) -> tuple[str, str]:
    """The tiny walk as a field recording: a receiver file and a sensors file with these start times (the
    simulation's own record of where the capture starts taken out)."""
    rx = ctx.tiny_rx_copy(edit=_set_attr(schema.RECEIVER_FRAMES, schema.START_UTC_NS_ATTR, np.int64(capture_utc_ns)))

    def edit(f: h5py.File) -> None:
        del f[schema.TRUTH_FRAMES].attrs[schema.CAPTURE_START_ATTR]
        f[schema.IMU].attrs[schema.START_UTC_NS_ATTR] = np.int64(log_utc_ns)
    return rx, ctx.h5(ctx.truth, "sensors.h5", edit)


@case(EXIT_BAD_INPUT)
def fuse_log_from_another_day_than_the_capture(ctx):
    day_ns = 86_400 * 10**9
    rx, sensors = _field_pair(ctx, 1_767_225_600 * 10**9 + day_ns, 1_767_225_600 * 10**9)
    return _fuse(ctx, rx, sensors, "--tower", "2000,2200"), [
        "2026-01-02T00:00:00", "2026-01-01T00:00:00", "+86400.0 s apart", "--time-offset"]


@case(EXIT_BAD_INPUT)
def fuse_time_offset_past_the_log(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--time-offset", "3600"), [str(ctx.rx), "do not overlap in time"]


@case(EXIT_USAGE)
def fuse_time_offset_not_a_number(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--time-offset", "nan"), ["--time-offset", "finite number"]


@case(EXIT_USAGE)
def receive_start_time_not_a_time(ctx):
    return ["-q", "receive", str(ctx.sim / "tiny-walk.sigmf-meta"), "--start-time", "10 o'clock", "-o", ctx.o()], [
        "--start-time", "bad ISO 8601 time"]


@case(EXIT_USAGE)
def fuse_tower_name_without_towers(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--tower-name", "Guishan"), ["--tower-name needs --towers"]


@case(EXIT_USAGE)
def fuse_tower_name_empty_name(ctx):
    towers = _towers(ctx, TOWER_ROW)
    return _fuse(ctx, ctx.rx, ctx.truth, "--towers", towers, "--tower-name", "Guishan,,"), ["--tower-name",
                                                                                             "empty names"]


@case(EXIT_USAGE)
def fuse_output_is_the_towers_file(ctx):
    towers = _towers(ctx, TOWER_ROW)
    return ["-q", "fuse", "--receiver", str(ctx.rx), "--sensors", str(ctx.truth), "--towers", towers, "-o",
            towers], ["-o", towers, "--towers"]


@case(EXIT_USAGE)
def fuse_start_text(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--start", "here"), ["--start"]


@case(EXIT_USAGE)
def fuse_seed_negative(ctx):
    return _fuse(ctx, ctx.rx, ctx.truth, "--seed=-4"), ["--seed"]


@case(EXIT_USAGE)
def fuse_output_is_the_receiver_file(ctx):
    rx = ctx.tiny_rx_copy()
    return ["-q", "fuse", "--receiver", rx, "--sensors", str(ctx.truth), "-o", rx], ["-o", rx, "--receiver"]


@case(EXIT_USAGE)
def fuse_output_is_the_sensors_file(ctx):
    sensors = ctx.copy(ctx.truth, "sensors.h5")
    return ["-q", "fuse", "--receiver", str(ctx.rx), "--sensors", sensors, "-o", sensors], ["-o", "--sensors"]


@case(EXIT_USAGE)
def fuse_missing_sensors_option(ctx):
    return ["-q", "fuse", "--receiver", str(ctx.rx), "-o", ctx.o()], ["--sensors"]


# --------------------------------------------------------------------------------------------------- report

@case(EXIT_BAD_INPUT)
def report_file_without_fusion(ctx):
    return ["-q", "report", str(ctx.rx), "-o", str(ctx.out / "report")], [str(ctx.rx), "/fusion"]


@case(EXIT_BAD_INPUT)
def report_nonexistent_results(ctx):
    path = str(ctx.tmp / "results.h5")
    return ["-q", "report", path, "-o", str(ctx.out / "report")], [path, "no such file"]


@case(EXIT_BAD_INPUT)
def report_results_without_pdr(ctx):
    path = ctx.h5(ctx.results, "results.h5", _drop(schema.PDR))
    return ["-q", "report", path, "-o", str(ctx.out / "report")], [path, "/pdr"]


@case(EXIT_BAD_INPUT)
def report_truth_without_truth_groups(ctx):
    truth = ctx.h5(ctx.truth, "truth.h5", _drop("truth"))
    return ["-q", "report", str(ctx.results), "--truth", truth, "-o", str(ctx.out / "report")], [truth, "/truth"]


@case(EXIT_BAD_INPUT)
def report_output_is_a_regular_file(ctx):
    blocker = ctx.write("report", "x")
    return ["-q", "report", str(ctx.results), "-o", blocker], [blocker, "not a folder"]


@case(EXIT_USAGE)
def report_output_is_the_results_file(ctx):
    path = ctx.copy(ctx.results)
    return ["-q", "report", path, "-o", path], ["-o", path, "RESULTS"]


# ------------------------------------------------------------------------------------------------- simulate

@case(EXIT_BAD_INPUT)
def simulate_toml_syntax_error(ctx):
    path = ctx.write("walk.toml", "[walk\nspeed_mps = 1.3\n")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path]


@case(EXIT_BAD_INPUT)
def simulate_toml_unknown_key(ctx):
    path = ctx.write("walk.toml", "[walk]\nspeed = 1.3\n")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "unknown key", "speed"]


@case(EXIT_BAD_INPUT)
def simulate_toml_wrong_typed_value(ctx):
    path = ctx.write("walk.toml", '[walk]\nspeed_mps = "brisk"\n')
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "speed_mps", "brisk"]


@case(EXIT_BAD_INPUT)
def simulate_toml_wrong_typed_list(ctx):
    path = ctx.write("walk.toml", '[walk]\nwaypoints_m = [[0, 0], [0, "north"]]\n')
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "waypoints_m"]


@case(EXIT_BAD_INPUT)
def simulate_toml_nan_value(ctx):
    path = ctx.write("walk.toml", "[receiver]\ncn_db = nan\n")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "cn_db", "finite"]


@case(EXIT_BAD_INPUT)
def simulate_toml_section_not_a_table(ctx):
    path = ctx.write("walk.toml", "walk = 3\n")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "walk", "table"]


@case(EXIT_BAD_INPUT)
def simulate_toml_binary_file(ctx):
    path = ctx.write("walk.toml", b"\xff\xfe\x00binary")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path]


@case(EXIT_BAD_INPUT)
def simulate_toml_missing(ctx):
    path = str(ctx.tmp / "walk.toml")
    return ["-q", "simulate", path, "--no-iq", "-o", str(ctx.out / "sim")], [path, "does not exist"]


@case(EXIT_USAGE)
def simulate_unknown_scenario_name(ctx):
    return ["-q", "simulate", "park-lop", "-o", str(ctx.out / "sim")], ["park-lop", "unknown scenario"]


@case(EXIT_USAGE)
def simulate_unknown_device(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--device", "rtl", "-o", str(ctx.out / "sim")], [
        "'rtl'", "unknown SDR device", "rtl-sdr"]


@case(EXIT_BAD_INPUT)
def simulate_toml_adc_bits_beyond_the_format(ctx):
    path = ctx.write("walk.toml", '[receiver]\nsample_format = "ci16"\nadc_bits = 20\n')
    return ["-q", "simulate", path, "--seconds", "0.01", "-o", str(ctx.out / "sim")], [
        "receiver.adc_bits", "2..16 for ci16", "20"]


@case(EXIT_BAD_INPUT)
def simulate_toml_drop_samples_reversed(ctx):
    path = ctx.write("walk.toml", "[receiver]\ndrops_per_minute = 10.0\ndrop_samples = [500, 5]\n")
    return ["-q", "simulate", path, "--seconds", "0.01", "-o", str(ctx.out / "sim")], [
        "receiver.drop_samples", "shortest first", "[500, 5]"]


@case(EXIT_USAGE)
def simulate_seconds_zero(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--seconds", "0", "-o", str(ctx.out / "sim")], ["--seconds"]


@case(EXIT_USAGE)
def simulate_seconds_negative(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--seconds=-2", "-o", str(ctx.out / "sim")], ["--seconds"]


@case(EXIT_USAGE)
def simulate_start_negative(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--start=-1", "-o", str(ctx.out / "sim")], ["--start"]


@case(EXIT_USAGE)
def simulate_rate_zero(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--rate", "0", "-o", str(ctx.out / "sim")], ["--rate"]


@case(EXIT_USAGE)
def simulate_rate_nan(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--rate", "nan", "-o", str(ctx.out / "sim")], ["--rate"]


@case(EXIT_USAGE)
def simulate_rate_text(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--rate", "2.4M", "-o", str(ctx.out / "sim")], ["--rate", "2.4M"]


@case(EXIT_USAGE)
def simulate_seed_negative(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--seed=-1", "-o", str(ctx.out / "sim")], ["--seed"]


@case(EXIT_USAGE)
def simulate_unknown_container(ctx):
    return ["-q", "simulate", str(TINY_WALK), "--container", "wav", "-o", str(ctx.out / "sim")], ["--container"]


@case(EXIT_BAD_INPUT)
def simulate_output_inside_a_regular_file(ctx):
    blocker = ctx.write("blocker", "x")
    return ["-q", "simulate", str(TINY_WALK), "--no-iq", "-o", blocker + "/sim"], [blocker, "not a folder"]


# ----------------------------------------------------------------------------------- run, evaluate, bench, demo

@case(EXIT_BAD_INPUT)
def run_missing_folder(ctx):
    folder = str(ctx.tmp / "nowhere")
    return ["-q", "run", folder, "-o", str(ctx.out / "run")], [folder, "not a folder"]


@case(EXIT_BAD_INPUT)
def run_folder_without_capture(ctx):
    (ctx.tmp / "set").mkdir()
    ctx.copy(ctx.truth, "set/truth.h5")
    return ["-q", "run", str(ctx.tmp / "set"), "-o", str(ctx.out / "run")], [str(ctx.tmp / "set"), "capture"]


@case(EXIT_BAD_INPUT)
def run_folder_without_sensors(ctx):
    ctx.capture(folder="set")
    return ["-q", "run", str(ctx.tmp / "set"), "-o", str(ctx.out / "run")], [str(ctx.tmp / "set"), "sensors"]


@case(EXIT_BAD_INPUT)
def run_folder_with_a_broken_capture(ctx):
    files = ctx.capture(fmt="ci16", folder="set")
    files.data.write_bytes(files.data.read_bytes()[:-1])
    ctx.copy(ctx.truth, "set/truth.h5")
    return ["-q", "run", str(ctx.tmp / "set"), "-o", str(ctx.out / "run")], [str(files.data), "half an IQ pair"]


@case(EXIT_USAGE)
def run_unknown_filter(ctx):
    return ["-q", "run", str(ctx.sim), "-o", str(ctx.out / "run"), "--filters", "pff"], ["--filters", "pff"]


@case(EXIT_USAGE)
def evaluate_zero_seeds(ctx):
    return ["-q", "evaluate", "park-loop", "--seeds", "0"], ["--seeds"]


@case(EXIT_USAGE)
def evaluate_unknown_scenario(ctx):
    return ["-q", "evaluate", "park-lop", "--seeds", "1"], ["park-lop", "unknown scenario"]


@case(EXIT_USAGE)
def evaluate_particles_zero(ctx):
    return ["-q", "evaluate", "park-loop", "--particles", "0"], ["--particles"]


@case(EXIT_USAGE)
def evaluate_unknown_filter(ctx):
    return ["-q", "evaluate", "park-loop", "--filters", "zupt"], ["--filters", "zupt"]


@case(EXIT_BAD_INPUT)
def evaluate_json_in_a_missing_folder(ctx):
    path = str(ctx.tmp / "missing" / "table.json")
    return ["-q", "evaluate", "park-loop", "--seeds", "1", "--json", path], ["--json", "does not exist"]


@case(EXIT_USAGE)
def evaluate_json_is_the_scenario_file(ctx):
    path = ctx.copy(TINY_WALK)
    return ["-q", "evaluate", path, "--seeds", "1", "--json", path], ["--json", path, "input"]


@case(EXIT_BAD_INPUT)
def bench_json_is_a_folder(ctx):
    return ["-q", "bench", "--quick", "--json", str(ctx.out)], ["--json", str(ctx.out), "is a folder"]


@case(EXIT_BAD_INPUT)
def bench_json_inside_a_regular_file(ctx):
    blocker = ctx.write("blocker", "x")
    return ["-q", "bench", "--quick", "--json", blocker + "/bench.json"], ["--json", blocker]


@case(EXIT_USAGE)
def demo_seconds_zero(ctx):
    return ["-q", "demo", "--seconds", "0", "-o", str(ctx.out / "demo")], ["--seconds"]


@case(EXIT_USAGE)
def demo_unknown_scenario(ctx):
    return ["-q", "demo", "--scenario", "nowhere", "-o", str(ctx.out / "demo")], ["nowhere", "unknown scenario"]


# --------------------------------------------------------------------------------------------------- runner

def _snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones too) with a hash of its content; folders as ``<dir>``."""
    out = {}
    for path in sorted(folder.rglob("*")):
        out[str(path.relative_to(folder))] = "<dir>" if path.is_dir() else hashlib.sha1(path.read_bytes()).hexdigest()
    return out


def run_cli(argv: list[str], capsys) -> tuple[int, str, str]:
    """``main(argv)`` in-process: exit code (argparse's SystemExit included), stdout, stderr."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else EXIT_USAGE
    out, err = capsys.readouterr()
    return code, out, err


def test_the_table_has_at_least_sixty_cases():
    assert len(CASES) >= 60


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input(name, tmp_path, request, monkeypatch, make_capture, capsys):
    entry = CASES[name]
    ctx = Ctx(tmp_path, request, monkeypatch, make_capture)
    argv, mentions = entry.build(ctx)
    capsys.readouterr()  # what building the inputs printed
    before = _snapshot(tmp_path)
    code, _, err = run_cli(argv, capsys)

    assert code == entry.code, err
    for word in mentions:
        assert word in err, f"stderr does not mention {word!r}:\n{err}"
    if "--debug" not in argv:
        assert "Traceback" not in err
    if code in (EXIT_BAD_INPUT, EXIT_INTERNAL) and "--debug" not in argv:
        command = next(arg for arg in argv if not arg.startswith("-"))
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"dtmbnav {command}: "), err
    after = _snapshot(tmp_path)
    if code == EXIT_OK:
        return
    new = {k: v for k, v in after.items() if before.get(k) != v}
    if code == EXIT_NO_RESULT:
        # The run's declared output may appear (complete, without rows); nothing else changes.
        assert set(new) <= {str(ctx.output.relative_to(tmp_path))}, new
        if ctx.output.exists():
            with h5py.File(ctx.output, "r") as f:
                assert f.attrs[schema.COMPLETE_ATTR]
                assert len(f[schema.RECEIVER_FRAMES]["t_s"]) == 0
        return
    assert after == before, f"the failed run changed the case folder: {new} / {set(before) - set(after)}"


def test_version_prints_the_package_version(capsys):
    code, out, _ = run_cli(["--version"], capsys)
    assert code == EXIT_OK
    assert out.strip() == f"dtmbnav {package_version()}"


def test_quiet_after_the_subcommand_silences_the_progress_bar(tiny_sim, tmp_path, capsys):
    argv = ["receive", str(tiny_sim / "tiny-walk.sigmf-meta"), "-o", str(tmp_path / "rx.h5")]
    code, _, err = run_cli([*argv, "-q"], capsys)
    assert code == EXIT_OK
    assert "S/s" not in err  # no tqdm rate
    code, _, err = run_cli(argv, capsys)
    assert code == EXIT_OK
    assert "S/s" in err

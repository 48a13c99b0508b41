"""``dtmbnav live`` checked as a user runs it: a simulated park walk replayed as it would come live.

The walk's 2.4 Msps cu8 capture is served by an in-process rtl_tcp server (:mod:`sim.rtl_tcp_replay`) at
real-time pace and its Sensor Logger export is pushed over HTTP as the app sends it
(:mod:`dtmbnav.simulation.phone_replay`), into ``dtmbnav live`` run as its own process. While it runs, its
``live.csv`` is followed: when each position arrives, on the host's clock and on the walk's. After it, the
same capture is received and the same phone log imported and fused by the batch commands (``receive``,
``sensors``, ``fuse``), with the same filter, time offset and start fix rule. Printed (Markdown):

- how often a position came (the longest wait between two, s of the host's clock) and how far its time
  trails the walk's newest sample, once the initial heading is confident;
- the final track's 95 % error (against the simulation's truth, in the walk's frame) live and batch;
- the live process's CPU time per second of stream (what a real-time run at 2.4 Msps costs) and its
  peak memory;
- the same walk with the rtl_tcp connection dropped mid-walk: the gap flagged in ``/receiver/frames``,
  the stream resumed, no position row lost (rows keep coming after the gap, every frame before it kept).

With ``--memory-minutes M`` a further run replays the capture and the phone log looped for M minutes of
stream, as fast as the live process takes them, and samples its resident memory.

    python -m dtmbnav.evaluation.live_check [--folder DIR] [--memory-minutes 30]

The walk is ``dtmbnav simulate park-loop --rate 2.4e6 --format cu8 --phone-log sensorlogger`` (made in
``--folder`` when not there yet): its scenario's seed, a tuning walk.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import re
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from dtmbnav.chain.live import output_paths
from dtmbnav.simulation.phone_replay import post, push_batches, push_readings, replay_push
from dtmbnav_core.records import FrameFlag, Track
from dtmbnav_core.sensors import read_walk_truth
from fusion.metrics import position_errors_m
from receiver.rtl_tcp import DEFAULT_POLICY
from sim.rtl_tcp_replay import RtlTcpReplay
from sim.scenario import load_scenario

#: The walk, its sample rate and the dongle's centre frequency.
SCENARIO = "park-loop"
RATE_HZ = 2.4e6
#: The live filter (the paper's) and its particles: the fusion's default.
FILTER = "pf"
#: Where the rtl_tcp connection is dropped in the outage run, s of stream, and for how long, s.
DROP_AT_S, OUTAGE_S = 40.0, 2.0


@dataclass
class LiveRun:
    """One ``dtmbnav live`` process over the replays.

    Attributes
    ----------
    folder : Path
        Its output folder.
    arrivals : list of (float, float, float, bool)
        Each new newest position as followed in ``live.csv``: (host seconds since the replays began, the walk's
        newest sample then, s, the newest row time written so far, s, whether a filtered row has come by then).
    cpu_s : float
        The process's CPU time (user + system), s.
    peak_rss_mb : float
        Its peak resident memory, MB.
    rss_mb : list of (float, float)
        (host seconds, resident memory MB) samples.
    returncode : int
    stderr : str
    """

    folder: Path
    arrivals: list
    cpu_s: float
    peak_rss_mb: float
    rss_mb: list
    returncode: int
    stderr: str


def free_port() -> int:
    """A TCP port free on this machine now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_walk(folder: Path) -> Path:
    """The simulated walk (module docstring), made once."""
    if not (folder / "truth.h5").exists():
        subprocess.run([sys.executable, "-m", "dtmbnav.cli", "simulate", SCENARIO, "--rate", str(RATE_HZ), "--format",
                        "cu8", "--phone-log", "sensorlogger", "-o", str(folder), "-q"], check=True)
    return folder


def _weinberg_k(folder: Path) -> float:
    with h5py.File(folder / "truth.h5") as f:
        return float(f["imu"].attrs["weinberg_k_m"])


def _phone_log(folder: Path) -> Path:
    return next(p for p in folder.iterdir() if p.is_dir())


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return math.nan


class _Follower:
    """Follows a growing CSV file (``tail -f``): the rows that completed since the last look."""

    def __init__(self, path: Path) -> None:
        self.path, self._offset, self._partial = path, 0, b""

    def new_rows(self) -> list[list[str]]:
        if not self.path.exists():
            return []
        with self.path.open("rb") as f:
            f.seek(self._offset)
            data = self._partial + f.read()
        self._offset += len(data) - len(self._partial)
        *lines, self._partial = data.split(b"\n")
        return [row for row in csv.reader(line.decode() for line in lines) if row and row[0] != "t_s"]


def run_live(folder: Path, out: Path, pace: float = 1.0, replay_kwargs: dict | None = None,
             phone_feed=None, stream_limit_s: float | None = None) -> LiveRun:
    """``dtmbnav live`` over the replays of ``folder``'s walk into ``out`` (module docstring).

    ``phone_feed(url, pace, stop)`` pushes the phone's batches (default: the log once, :func:`replay_push`);
    with ``stream_limit_s`` the live process is stopped (SIGINT, as Ctrl-C) once that much stream was sent.
    """
    capture = next(folder.glob("*.sigmf-data"))
    push_port = free_port()
    with RtlTcpReplay(capture, RATE_HZ, pace=pace, **(replay_kwargs or {})) as server:
        command = [sys.executable, "-m", "dtmbnav.cli", "live", server.url, "--phone", f"sensorlogger:127.0.0.1:{push_port}",
                   "--towers", str(folder / "towers.csv"), "--center", "666e6", "--rate", str(RATE_HZ),
                   "--weinberg-k", str(_weinberg_k(folder)), "--filters", FILTER, "--reconnects", "2",
                   # The capture starts with the phone log; the source drops its settling samples first.
                   "--time-offset", str(DEFAULT_POLICY.settle_s), "-o", str(out), "-q"]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)   # earlier children's (the walk's simulation)
        child = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        url = f"http://127.0.0.1:{push_port}/"
        for _ in range(600):   # the push server is up once it answers (an empty batch is refused: 400)
            try:
                post(url, b"{}")
                break
            except OSError:
                time.sleep(0.1)
        begun = time.monotonic()
        stop = threading.Event()
        feed = phone_feed or (lambda url, pace, stop: replay_push([_phone_log(folder)], url, pace, stop=stop))
        pusher = threading.Thread(target=feed, args=(url, pace, stop), daemon=True)
        pusher.start()
        arrivals, rss = [], []
        follower = _Follower(output_paths(out)["csv"])
        while child.poll() is None:
            now = time.monotonic() - begun
            rows = follower.new_rows()
            # The newest position is the latest time written so far (a batch of re-sent, older rows may be read
            # before the newer rows of the same update are flushed).
            newest = max((float(r[0]) for r in rows), default=-math.inf)
            if newest > (arrivals[-1][2] if arrivals else -math.inf):
                arrivals.append((now, now * pace, newest, any(r[3] == "filtered" for r in rows)
                                 or bool(arrivals and arrivals[-1][3])))
            rss.append((now, _rss_mb(child.pid)))
            if stream_limit_s is not None and server.sent_bytes / 2 / RATE_HZ >= stream_limit_s:
                child.send_signal(signal.SIGINT)
                stream_limit_s = None
            time.sleep(0.1)
        stop.set()
        stderr = child.stderr.read()
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = usage.ru_utime + usage.ru_stime - before.ru_utime - before.ru_stime
    peak_mb = max((mb for _, mb in rss if np.isfinite(mb)), default=math.nan)
    return LiveRun(out, arrivals, cpu_s, peak_mb, rss, child.returncode, stderr)


def batch_p95(folder: Path, work: Path) -> tuple[float, Track]:
    """The batch commands on the same walk: the filter's 95 % error against the truth, m, and its track."""
    capture = next(folder.glob("*.sigmf-meta"))
    run = [sys.executable, "-m", "dtmbnav.cli"]
    subprocess.run([*run, "sensors", str(_phone_log(folder)), "-o", str(work / "sensors.h5"), "-q"], check=True)
    subprocess.run([*run, "receive", str(capture), "-o", str(work / "rx.h5"), "-q"], check=True)
    subprocess.run([*run, "fuse", "--receiver", str(work / "rx.h5"), "--sensors", str(work / "sensors.h5"),
                    "--towers", str(folder / "towers.csv"), "--weinberg-k", str(_weinberg_k(folder)), "--filters",
                    FILTER, "--time-offset", "0", "-o", str(work / "fused.h5"), "-q"], check=True)
    track = _track(work / "fused.h5")
    return _p95(folder, work / "sensors.h5", track), track


def _track(path: Path) -> Track:
    with h5py.File(path) as f:
        g = f[f"fusion/{FILTER}"]
        return Track(*(g[k][:] for k in ("t_s", "x_m", "y_m", "heading_rad", "speed_mps")))


def _p95(folder: Path, frame_file: Path, track: Track) -> float:
    """95 % error of ``track`` (in the frame of ``frame_file``'s origin, the phone's first fix) against the truth."""
    from dtmbnav.field.towers import read_towers
    from dtmbnav_core.geodetic import tower_in_sensors_frame

    truth = read_walk_truth(folder / "truth.h5").track
    scenario = load_scenario(SCENARIO)
    tower = read_towers(folder / "towers.csv")[0]
    x, y, _ = tower_in_sensors_frame(frame_file, tower.point())
    shift = (x - scenario.tower.x_m, y - scenario.tower.y_m)
    moved = Track(truth.t_s, truth.x_m + shift[0], truth.y_m + shift[1], truth.heading_rad, truth.speed_mps)
    return float(np.percentile(position_errors_m(track, moved), 95))


def timeliness(run: LiveRun, walk_s: float) -> tuple[float, float, float]:
    """From the first filtered position to the end of the phone's log (``walk_s``, s): the longest wait between two
    new newest-positions (host s), and the median and largest lag of the newest position's time behind the walk's
    newest sample sent (s)."""
    first = next((i for i, a in enumerate(run.arrivals) if a[3]), None)
    if first is None:
        return math.nan, math.nan, math.nan
    after = [a for a in run.arrivals[first:] if a[1] <= walk_s]
    if len(after) < 2:
        return math.nan, math.nan, math.nan
    waits = np.diff([a[0] for a in after])
    lags = np.array([a[1] - a[2] for a in after])
    return float(np.max(waits)), float(np.median(lags)), float(np.max(lags))


def outage_kept(run: LiveRun) -> dict[str, object]:
    """The dropped connection's traces: GAP frames, frames after the first gap, rows after it."""
    with h5py.File(output_paths(run.folder)["receiver"]) as f:
        frames = f["receiver/frames"]
        flags, t = frames["flags"][:].astype(np.int64), frames["t_s"][:]
        outages = int(frames.attrs.get("outages", 0))
    gap_t = t[(flags & int(FrameFlag.GAP)) != 0]
    rows = list(csv.DictReader(output_paths(run.folder)["csv"].open()))
    rows_after = sum(float(r["t_s"]) > gap_t[0] + DEFAULT_POLICY.settle_s for r in rows) if len(gap_t) else 0
    return {"outages": outages, "gap_frames": len(gap_t), "frames_after_gap": int(np.sum(t > gap_t[0])) if len(gap_t)
            else 0, "rows_after_gap": rows_after}


def looped_feed(folder: Path, minutes: float):
    """A phone feed that pushes the log again and again (its times moved on by its length each lap) for
    ``minutes`` of walk, as fast as the live process takes it."""
    batches = push_batches(push_readings([_phone_log(folder)]))
    span_ns = batches[-1][0] - batches[0][0] + int(1e9)

    def feed(url: str, pace: float, stop: threading.Event) -> None:
        message_id, lap = 0, 0
        while lap * span_ns / 1e9 < minutes * 60.0 and not stop.is_set():
            for _, message in batches:
                moved = {**message, "messageId": message_id,
                         "payload": [{**r, "time": r["time"] + lap * span_ns} for r in message["payload"]]}
                while post(url, moved) == 503 and not stop.is_set():   # the live process is behind: wait
                    time.sleep(0.5)
                message_id += 1
            lap += 1
    return feed


def check(folder: Path, memory_minutes: float = 0.0) -> tuple[str, str, bool]:
    """Every run of the module docstring in ``folder``: (the walk described, the Markdown table, whether both
    live processes ended well)."""
    walk = make_walk(folder / "walk")
    stream_s = os.path.getsize(next(walk.glob("*.sigmf-data"))) / 2 / RATE_HZ
    live = run_live(walk, folder / "live")
    batch, _ = batch_p95(walk, _fresh(folder / "batch"))
    live_p95 = _p95(walk, output_paths(live.folder)["live"], _track(output_paths(live.folder)["live"]))
    wait_s, lag_median_s, lag_s = timeliness(live, stream_s)
    dropped = run_live(walk, folder / "dropped", replay_kwargs={"drop_after_s": DROP_AT_S, "outage_s": OUTAGE_S})
    kept = outage_kept(dropped)
    lines = ["| check | figure |", "|---|---|",
             f"| longest wait between two positions, after the heading is confident | {wait_s:.2f} s |",
             f"| lag of the newest position behind the phone's newest sample sent, after it: median / largest | "
             f"{lag_median_s:.2f} s / {lag_s:.2f} s |",
             f"| final {FILTER.upper()} 95 % error, live / batch | {live_p95:.2f} m / {batch:.2f} m "
             f"({live_p95 / batch - 1:+.1%}) |",
             f"| live process CPU per second of 2.4 Msps stream (start-up included) | {live.cpu_s / stream_s:.2f} core "
             f"({_cpu_split(live.stderr, stream_s)}) |",
             f"| live process peak memory | {live.peak_rss_mb:.0f} MB |",
             f"| dropped connection at {DROP_AT_S:g} s for {OUTAGE_S:g} s | {kept['outages']} outage(s), "
             f"{kept['gap_frames']} GAP frame(s), {kept['frames_after_gap']} frames and {kept['rows_after_gap']} "
             "positions after it |"]
    if memory_minutes > 0:
        lines += memory_lines(walk, folder / "memory", memory_minutes)
    described = (f"Park walk (`{SCENARIO}`, 2.4 Msps cu8, {stream_s:.0f} s) replayed over rtl_tcp and Sensor "
                 "Logger's HTTP push into `dtmbnav live`, against `receive`, `sensors` and `fuse` on the same files")
    return described, "\n".join(lines), live.returncode == 0 and dropped.returncode == 0


def _cpu_split(stderr: str, stream_s: float) -> str:
    """The process after its start-up, the receiver's and the fusion's shares, as the live process's last line
    states them, per stream second."""
    match = re.search(r"CPU: receiver ([0-9.]+) s, fusion ([0-9.]+) s, the whole process [0-9.]+ s \(([0-9.]+) s from "
                      r"the first frame on\)", stderr)
    if match is None:
        return "split not stated"
    receiver, fusion, running = (float(v) / stream_s for v in match.groups())
    return f"after start-up {running:.2f}: receiver thread {receiver:.2f}, fusion thread {fusion:.2f}"


def live_section(config) -> object:
    """The results file's ``live`` section (:mod:`dtmbnav.evaluation.results`)."""
    import tempfile

    from dtmbnav.evaluation.results_data import Prose, Section, Table

    with tempfile.TemporaryDirectory() as folder:
        described, table, _ = check(Path(folder))
    return Section("live", "The live command over a replayed walk", "dtmbnav results --sections live",
                   (Prose(f"{described} (`python -m dtmbnav.evaluation.live_check`)."), Table.parse(table)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--folder", type=Path, default=Path("live-check"), help="where the walk and the runs go")
    parser.add_argument("--memory-minutes", type=float, default=0.0, help="also the looped memory run (minutes)")
    args = parser.parse_args(argv)
    described, table, ok = check(args.folder, args.memory_minutes)
    print(f"{described} (`python -m dtmbnav.evaluation.live_check`).\n\n{table}")
    return 0 if ok else 1


def memory_lines(walk: Path, out: Path, minutes: float) -> list[str]:
    """The looped run's resident memory, at its second minute of host time and at its end."""
    run = run_live(walk, out, pace=math.inf, replay_kwargs={"loop": True}, phone_feed=looped_feed(walk, minutes),
                   stream_limit_s=minutes * 60.0)
    rss = np.array(run.rss_mb)
    early = rss[np.searchsorted(rss[:, 0], 120.0), 1] if rss[-1, 0] > 120 else math.nan
    return [f"| resident memory over {minutes:g} min of stream looped as fast as it goes: after 2 min / at the "
            f"end ({rss[-1, 0] / 60:.0f} min) | {early:.0f} MB / {rss[-1, 1]:.0f} MB |"]


def _fresh(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return folder


if __name__ == "__main__":
    sys.exit(main())

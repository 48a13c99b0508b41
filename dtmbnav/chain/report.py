"""Report folder: trajectory map, every range channel vs truth, error CDF and a summary table.

Reads a results file (``/receiver/frames``, ``/pdr``, ``/fusion/<filter>``)
and, when available, the truth (``/truth``) of the same walk. Figures are PNG
(matplotlib, Agg backend); the table is written as Markdown and JSON, with the
paper's figures (``docs/method.md`` §6) next to ours. Where the results' ENU
frame has a geodetic origin (stored by ``fuse`` from a sensors file of
``dtmbnav sensors``, or given as ``report --origin``), the tracks, the GNSS
fixes and the towers also go onto WGS84 as map files (:mod:`dtmbnav.field.maps`).

Each filter's smoothed track (``/fusion/<filter>/smoothed``) is shown beside
its filtered one as ``<filter> smoothed``. A track that states its error has
its 95 % ellipse drawn along it every :data:`ELLIPSE_EVERY_S` seconds, its
truth coverage and NEES in the table (:func:`fusion.metrics.stated_error_stats`),
and a 95 % radius per point on the map files.
"""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend chosen first: reports run headless)
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from dtmbnav.chain.inputs import read_receiver_frames  # noqa: E402
from dtmbnav.chain.paper import paper_figures  # noqa: E402
from dtmbnav.field.maps import (  # noqa: E402
    KIND_FILTER,
    KIND_FIX,
    KIND_PDR,
    KIND_SMOOTHED,
    KIND_TOWER,
    KIND_TRUTH,
    MapPoint,
    MapTrack,
    write_map_files,
)
from dtmbnav_core import schema  # noqa: E402
from dtmbnav_core.geodetic import GeodeticPoint, read_origin, to_geodetic  # noqa: E402
from dtmbnav_core.h5io import atomic_folder, open_h5, read_attrs, read_columns, read_fused_track  # noqa: E402
from dtmbnav_core.records import ELLIPSE_95_CHI2, FusedTrack, PdrSteps, Track  # noqa: E402
from dtmbnav_core.sensors import read_tower, read_walk_truth  # noqa: E402
from fusion.metrics import (  # noqa: E402
    PDR_AT_FIX,
    PDR_BASELINE,
    error_cdf,
    error_stats,
    heading_error_rad,
    pdr_baselines,
    place_pdr,
    position_errors_m,
    stated_error_stats,
)

#: What a smoothed track's name adds to its filter's in the report (``pf smoothed``).
SMOOTHED_SUFFIX = " smoothed"
#: Seconds between the 95 % ellipses drawn along a track that states its error.
ELLIPSE_EVERY_S = 10.0


@dataclass(frozen=True)
class SummaryRow:
    """One line of the summary table (errors in metres)."""

    estimate: str
    p68_m: float
    p95_m: float
    max_m: float
    reduction_95: float | None
    paper: tuple[float, float, float] | None
    in_ellipse_95: float | None = None
    mean_nees: float | None = None


def load_results(results_path: str | os.PathLike) -> tuple[dict[str, FusedTrack], PdrSteps, float,
                                                           tuple[float, float]]:
    """Fused tracks by filter (and ``<filter> smoothed`` where the file has it), the PDR steps, the initial
    heading and the start P0 used.

    A file written before the start was recorded gives the first filter's first
    position for it (a filter that moved during the first standstill moves it too);
    one written before the tracks stated their error gives them NaN covariance.
    """
    with h5py.File(results_path, "r") as f:
        if schema.FUSION not in f:
            raise ValueError(f"{results_path}: no /{schema.FUSION} group (run 'dtmbnav fuse' or 'dtmbnav run' first)")
        names = list(f[schema.FUSION])
        groups = {name: schema.fusion_group(name) for name in names}
        groups.update({name + SMOOTHED_SUFFIX: schema.fusion_group(name, smoothed=True) for name in names
                       if schema.SMOOTHED in f[schema.fusion_group(name)]})
        tracks = {name: read_fused_track(f, group) for name, group in groups.items()}
    pdr_cols = read_columns(results_path, schema.PDR)
    pdr = PdrSteps(**{k: pdr_cols[k] for k in (*schema.TRACK_COLUMNS, "step_length_m")})
    attrs = read_attrs(results_path, schema.fusion_group(names[0]))
    first = tracks[names[0]]
    start = tuple(float(attrs.get(name, default)) for name, default in zip(schema.FUSION_START_ATTRS,
                                                                           (first.x_m[0], first.y_m[0])))
    return tracks, pdr, float(attrs[schema.INITIAL_HEADING_ATTR]), (start[0], start[1])


def summary_rows(truth: Track, estimates: dict[str, Track], scenario_name: str) -> list[SummaryRow]:
    """68/95/max of every estimate against the truth, with the 95 % reduction vs the ``pdr`` row."""
    stats = {name: error_stats(position_errors_m(track, truth)) for name, track in estimates.items()}
    stated = {name: stated_error_stats(track, truth) for name, track in estimates.items() if stated_error(track)}
    pdr95 = stats[PDR_BASELINE].p95_m if PDR_BASELINE in stats else None
    figures = paper_figures(scenario_name)
    paper = {PDR_BASELINE: figures.pdr, "pf": figures.pf} if figures else {}
    return [SummaryRow(name, s.p68_m, s.p95_m, s.max_m,
                       None if name == PDR_BASELINE or pdr95 is None else 1.0 - s.p95_m / pdr95, paper.get(name),
                       stated[name].in_ellipse_95 if name in stated else None,
                       stated[name].mean_nees if name in stated else None)
            for name, s in stats.items()]


def format_rows(rows: list[SummaryRow]) -> str:
    """The summary as a Markdown table."""
    lines = ["| estimate | 68 % (m) | 95 % (m) | max (m) | 95 % reduction vs PDR | in 95 % ellipse | NEES | "
             "paper 68/95/max |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        red = "" if r.reduction_95 is None else f"{100 * r.reduction_95:.0f} %"
        inside = "" if r.in_ellipse_95 is None else f"{100 * r.in_ellipse_95:.0f} %"
        nees = "" if r.mean_nees is None else f"{r.mean_nees:.2f}"
        paper = "" if r.paper is None else "/".join(f"{v:.2f}" for v in r.paper)
        lines.append(f"| {r.estimate} | {r.p68_m:.2f} | {r.p95_m:.2f} | {r.max_m:.2f} | {red} | {inside} | {nees} | "
                     f"{paper} |")
    return "\n".join(lines)


def _scenario_name(truth_path: str | os.PathLike) -> str:
    text = str(read_attrs(truth_path, schema.TRUTH_TRAJECTORY).get("scenario", ""))
    return tomllib.loads(text).get("name", "") if text else ""


def stated_error(track: Track) -> bool:
    """Whether ``track`` is a fused track that states its error (not the PDR, not an old file's)."""
    return isinstance(track, FusedTrack) and track.has_stated_error()


def ellipse_rows(t_s: np.ndarray, every_s: float = ELLIPSE_EVERY_S) -> np.ndarray:
    """Rows of a track, the first and then the first at or after each further ``every_s`` seconds."""
    marks = np.arange(t_s[0], t_s[-1] + 1e-9, every_s)
    return np.unique(np.searchsorted(t_s, marks))


def ellipse_axes(covariance_m2: np.ndarray) -> tuple[float, float, float]:
    """Full width and height (m) of a 2-D covariance's 95 % ellipse (:data:`ELLIPSE_95_CHI2`), and the angle of
    its width from east, counter-clockwise, deg (matplotlib's ``Ellipse``)."""
    values, vectors = np.linalg.eigh(covariance_m2)
    width, height = 2.0 * np.sqrt(ELLIPSE_95_CHI2 * np.maximum(values[::-1], 0.0))
    major = vectors[:, 1]
    return float(width), float(height), float(np.degrees(np.arctan2(major[1], major[0])))


def draw_ellipses(ax, track: FusedTrack, colour: str) -> None:
    """The track's stated 95 % ellipse every :data:`ELLIPSE_EVERY_S` seconds."""
    covariances = track.position_covariance_m2()
    for i in ellipse_rows(track.t_s):
        width, height, angle = ellipse_axes(covariances[i])
        ax.add_patch(Ellipse((track.x_m[i], track.y_m[i]), width, height, angle=angle, fill=False, lw=0.6,
                             color=colour, alpha=0.6))


def plot_trajectories(path: Path, truth: Track | None, estimates: dict[str, Track], tower_xy: tuple[float, float] | None):
    fig, ax = plt.subplots(figsize=(7, 7))
    if truth is not None:
        ax.plot(truth.x_m, truth.y_m, "k-", lw=2.5, label="truth")
    for name, track in estimates.items():
        style = "--" if name == PDR_BASELINE else ":" if name.endswith(SMOOTHED_SUFFIX) else "-"
        (line,) = ax.plot(track.x_m, track.y_m, style, lw=1.2, label=name)
        if stated_error(track):
            draw_ellipses(ax, track, line.get_color())
    if tower_xy is not None:
        span = max(np.ptp(truth.x_m), np.ptp(truth.y_m)) if truth is not None else 50.0
        bearing = np.arctan2(tower_xy[0] - truth.x_m[0], tower_xy[1] - truth.y_m[0]) if truth is not None else 0.0
        ax.annotate("to tower", xy=(truth.x_m[0] + 0.4 * span * np.sin(bearing),
                                    truth.y_m[0] + 0.4 * span * np.cos(bearing)),
                    xytext=(truth.x_m[0], truth.y_m[0]), arrowprops={"arrowstyle": "->", "color": "grey"})
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Trajectories")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


#: The range channels of ``/receiver/frames`` the fusion takes, with their plot titles: the SI carriers' range,
#: tower 0's first path, and the clock-free differences of towers 1 and 2 to tower 0 (docs/paths.md).
RANGE_CHANNELS = (("range_change_m", "SI carriers (eq. 11)", None),
                  ("first_path_range_change_m", "first path, tower 0", (0, None)),
                  ("range_difference_change_1_m", "tower 1 - tower 0 (clock-free)", (1, 0)),
                  ("range_difference_change_2_m", "tower 2 - tower 0 (clock-free)", (2, 0)))


def direct_path_ranges(truth_paths: dict[str, np.ndarray] | None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per tower, the times (s) and length (m) of its direct path in ``/truth/paths`` (empty without it)."""
    if truth_paths is None:
        return {}
    direct = truth_paths["kind"] == 0
    return {int(k): (truth_paths["t_s"][direct & (truth_paths["tower_id"] == k)],
                     truth_paths["range_m"][direct & (truth_paths["tower_id"] == k)])
            for k in np.unique(truth_paths["tower_id"][direct])}


def true_channel_m(channel: tuple[int, int | None] | None, t_s: np.ndarray, truth_frames: dict[str, np.ndarray],
                   direct: dict[int, tuple[np.ndarray, np.ndarray]]) -> np.ndarray | None:
    """The truth of one range channel at ``t_s`` (capture clock): tower 0's range for the SI carriers, a
    tower's direct path, or the difference of two towers' direct paths; None where the truth lacks it."""
    def direct_range(k: int) -> np.ndarray | None:
        if k in direct:
            return np.interp(t_s, *direct[k])
        return np.interp(t_s, truth_frames["t_s"], truth_frames["range_m"]) if k == 0 else None

    if channel is None:
        return np.interp(t_s, truth_frames["t_s"], truth_frames["range_m"])
    tower, minus = channel
    value = direct_range(tower)
    if value is None or minus is None:
        return value
    other = direct_range(minus)
    return None if other is None else value - other


def plot_ranges(path: Path, frames: dict[str, np.ndarray], time_offset_s: float, truth_frames: dict | None,
                truth_paths: dict[str, np.ndarray] | None = None) -> None:
    """Every range channel of the receiver file, and with truth its error, one row per channel.

    Each channel is a change since its first measured frame, so the truth is
    drawn as the change of the true range since that frame.
    """
    channels = [(column, title, channel) for column, title, channel in RANGE_CHANNELS
                if column in frames and np.isfinite(frames[column]).any()]
    direct = direct_path_ranges(truth_paths)
    fig, axes = plt.subplots(len(channels), 2, figsize=(11, 2.6 * len(channels) + 0.6), sharex=True, squeeze=False)
    t_rx = frames["t_s"]
    for (column, title, channel), (ax, ax_err) in zip(channels, axes):
        measured = frames[column]
        ok = np.isfinite(measured)
        ax.plot(t_rx[ok] + time_offset_s, measured[ok], ".", ms=1.5, label="receiver")
        truth = None if truth_frames is None else true_channel_m(channel, t_rx, truth_frames, direct)
        if truth is not None:
            first = np.argmax(ok)
            change = truth - truth[first]
            ax.plot(t_rx + time_offset_s, change, "k--", lw=1, label="truth")
            ax_err.plot(t_rx[ok] + time_offset_s, measured[ok] - change[ok], ".", ms=1.5)
        ax.set_ylabel("change (m)")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
        ax_err.set_ylabel("error (m)")
        ax_err.set_title(f"{title}: receiver - truth", fontsize=9)
        ax_err.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _truth_paths(truth_path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """``/truth/paths`` of a truth file (None in a file written before it existed)."""
    with h5py.File(truth_path, "r") as f:
        present = schema.TRUTH_PATHS in f
    return read_columns(truth_path, schema.TRUTH_PATHS) if present else None


def plot_cdf(path: Path, errors: dict[str, np.ndarray]):
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, err in errors.items():
        x, p = error_cdf(err)
        ax.plot(x, p, label=name)
    ax.axhline(0.95, color="grey", lw=0.8, ls=":")
    ax.axhline(0.68, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("position error (m)")
    ax.set_ylabel("CDF")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


#: The summary's line for a report without map files.
NO_MAP_NOTE = ("no map files: the results have no geodetic origin (local metres, e.g. a simulated walk); "
               "'report --origin LAT,LON[,H]' places them on the map")


def _has_group(path: str | os.PathLike, name: str) -> bool:
    with h5py.File(path, "r") as f:
        return name in f


def map_towers(results_path: str | os.PathLike, truth_path: str | os.PathLike | None,
               origin: GeodeticPoint) -> list[MapPoint]:
    """The towers the filters used (``/fusion`` attributes), else the truth's; empty where neither has them.

    Each tower goes onto WGS84 at its height above the receiver's antenna where the results record it
    (as ``fuse`` put it), else at up 0 m.
    """
    attrs = read_attrs(results_path, schema.FUSION)
    if all(name in attrs for name in schema.FUSION_TOWER_ATTRS):
        x, y, up = (np.atleast_1d(np.asarray(attrs[name], dtype=np.float64)) for name in schema.FUSION_TOWER_ATTRS)
    elif truth_path is not None:
        paths_attrs = read_attrs(truth_path, schema.TRUTH_PATHS) if _has_group(truth_path, schema.TRUTH_PATHS) else {}
        if "towers_x_m" in paths_attrs and "towers_y_m" in paths_attrs:
            x, y = (np.atleast_1d(np.asarray(paths_attrs[n], dtype=np.float64)) for n in ("towers_x_m", "towers_y_m"))
        else:
            x, y = (np.array([v]) for v in read_tower(truth_path)[:2])
        up = np.zeros_like(x)
    else:
        return []
    lat, lon = to_geodetic(x, y, up, origin)
    return [MapPoint(f"tower {k}", KIND_TOWER, float(a), float(b)) for k, (a, b) in enumerate(zip(lat, lon))]


def map_fixes(results_path: str | os.PathLike, truth_path: str | os.PathLike | None,
              origin: GeodeticPoint) -> list[MapPoint]:
    """The GNSS fixes of the results file's ``/gnss`` (copied by ``fuse``), else of the truth file's; at up 0 m."""
    source = results_path if _has_group(results_path, schema.GNSS) else truth_path
    if source is None or not _has_group(source, schema.GNSS):
        return []
    gnss = read_columns(source, schema.GNSS)
    lat, lon = to_geodetic(gnss["x_m"], gnss["y_m"], 0.0, origin)
    return [MapPoint(f"GNSS fix at {t:.1f} s", KIND_FIX, float(a), float(b))
            for t, a, b in zip(gnss["t_s"], lat, lon)]


def map_tracks(estimates: dict[str, Track], truth: Track | None, origin: GeodeticPoint) -> list[MapTrack]:
    """The truth (when given), ``pdr@fix`` and every filter's track (and smoothed track) on WGS84, at up 0 m,
    each filter's with its 95 % radius per point where it states its error
    (:meth:`~dtmbnav_core.records.FusedTrack.accuracy_radius_m`).

    The ``pdr`` baseline is left out: it is placed with the truth's start and heading, which a
    user in the field does not have.
    """
    def kind(name: str) -> str:
        return KIND_PDR if name == PDR_AT_FIX else KIND_SMOOTHED if name.endswith(SMOOTHED_SUFFIX) else KIND_FILTER

    named = ([("truth", KIND_TRUTH, truth)] if truth is not None else []) + [
        (name, kind(name), track) for name, track in estimates.items() if name != PDR_BASELINE]
    return [MapTrack(name, kind, *to_geodetic(track.x_m, track.y_m, 0.0, origin),
                     accuracy_m=track.accuracy_radius_m() if stated_error(track) else None)
            for name, kind, track in named]


def write_report(results_path: str | os.PathLike, out_dir: str | os.PathLike,
                 truth_path: str | os.PathLike | None = None, origin: GeodeticPoint | None = None) -> Path:
    """Write the report folder for a results file; returns the folder.

    Without a truth file the trajectory and range plots are drawn without
    truth and no error table is made. With a geodetic origin, ``origin``
    (height 0 m where not given) or else the one the results file holds,
    the map files ``tracks.geojson``, ``tracks.gpx`` and ``map.html`` are
    written too; without one the summary says there are none.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tracks, pdr, heading, start_fix_xy = load_results(results_path)
    frames = read_columns(results_path, schema.RECEIVER_FRAMES)
    truth = truth_frames = truth_paths = None
    tower = None
    offset = 0.0
    estimates = {PDR_AT_FIX: place_pdr(pdr, *start_fix_xy, heading), **tracks}
    if truth_path is not None:
        walk_truth = read_walk_truth(truth_path)
        truth = walk_truth.track
        truth_frames = read_columns(truth_path, schema.TRUTH_FRAMES)
        truth_paths = _truth_paths(truth_path)
        offset = float(read_attrs(truth_path, schema.TRUTH_FRAMES).get(schema.CAPTURE_START_ATTR, 0.0))
        tower = read_tower(truth_path)[:2]
        baselines, true_heading = pdr_baselines(pdr, truth, walk_truth.walk_start_t_s, start_fix_xy, heading)
        estimates = {**baselines, **tracks}
        heading_error_deg = float(np.rad2deg(heading_error_rad(heading, true_heading)))
    plot_trajectories(out / "trajectory.png", truth, estimates, tower)
    plot_ranges(out / "range.png", frames, offset, truth_frames, truth_paths)
    summary: dict = {"results": str(results_path), "initial_heading_deg": float(np.rad2deg(heading))}
    origin = origin.with_height(0.0) if origin is not None else read_origin(results_path)
    written: list[Path] = []
    if origin is not None:
        points = map_fixes(results_path, truth_path, origin) + map_towers(results_path, truth_path, origin)
        written = write_map_files(out, map_tracks(estimates, truth, origin), points)
        summary["map_origin"] = [origin.lat_deg, origin.lon_deg, origin.height_m]
    map_line = NO_MAP_NOTE if origin is None else (
        f"map: {', '.join(p.name for p in written)} (ENU origin {origin.lat_deg:.7f}, {origin.lon_deg:.7f} deg, "
        f"{origin.height_m:.1f} m)")
    summary["map"] = map_line
    summary["map_files"] = [p.name for p in written]
    if truth is not None:
        errors = {name: position_errors_m(track, truth) for name, track in estimates.items()}
        plot_cdf(out / "error_cdf.png", errors)
        rows = summary_rows(truth, estimates, _scenario_name(truth_path))
        table = format_rows(rows)
        summary["initial_heading_error_deg"] = heading_error_deg
        (out / "summary.md").write_text(
            f"# dtmbnav report\n\nResults: `{results_path}`  \nTruth: `{truth_path}`  \n"
            f"Initial heading (eq. 15): {np.rad2deg(heading):.1f} deg, {heading_error_deg:.1f} deg from the "
            f"true {np.rad2deg(true_heading) % 360:.1f} deg\n\n{table}\n\n"
            "`pdr` is placed as the paper reports PDR error (true start, true initial heading); `pdr@fix` "
            f"starts like the filters, at the GNSS fix with the eq. 15 heading.\n\n{map_line}\n")
        summary["rows"] = [asdict(r) for r in rows]
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return out


def receiver_accuracy(frames: dict[str, np.ndarray], truth_frames: dict[str, np.ndarray]) -> dict[str, float]:
    """Receiver against the simulator's truth, matched by arrival time.

    Returns the clock-offset error (f_s used minus the true mean CFO of the
    clock), the RMSE of 1 s means of the radial velocity, and the 95th
    percentile / max of the integrated-range error, m.
    """
    t, t_true = frames["t_s"], truth_frames["t_s"]
    velocity_true = np.interp(t, t_true, truth_frames["radial_velocity_mps"])
    range_true = np.interp(t, t_true, truth_frames["range_m"])
    ok = np.isfinite(frames["velocity_mps"]) & np.isfinite(frames["range_change_m"])
    second = np.floor(t[ok]).astype(int)
    counts = np.bincount(second)
    used = counts > 0
    mean_v = np.bincount(second, frames["velocity_mps"][ok])[used] / counts[used]
    mean_v_true = np.bincount(second, velocity_true[ok])[used] / counts[used]
    range_err = np.abs(frames["range_change_m"][ok] - (range_true[ok] - range_true[ok][0]))
    return {"velocity_rmse_1s_mps": float(np.sqrt(np.mean((mean_v - mean_v_true) ** 2))),
            "range_error_p95_m": float(np.percentile(range_err, 95)), "range_error_max_m": float(range_err.max()),
            "frames": int(len(t)), "seconds": float(t[-1] - t[0])}


def write_receiver_report(receiver_path: str | os.PathLike, out_dir: str | os.PathLike,
                          truth_path: str | os.PathLike | None = None) -> Path:
    """Report of a receiver run alone: range plot and, with truth, its accuracy."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    frames = read_columns(receiver_path, schema.RECEIVER_FRAMES)
    attrs = read_attrs(receiver_path, schema.RECEIVER_FRAMES)
    truth_frames = read_columns(truth_path, schema.TRUTH_FRAMES) if truth_path is not None else None
    truth_paths = _truth_paths(truth_path) if truth_path is not None else None
    plot_ranges(out / "range.png", frames, 0.0, truth_frames, truth_paths)
    lines = ["# dtmbnav receiver report", "", f"Capture results: `{receiver_path}`", "",
             f"- header mode {attrs.get('pn_mode')}, SI word {attrs.get('si_index')}, "
             f"f_s = {float(attrs.get('clock_offset_hz', np.nan)):.2f} Hz, {len(frames['t_s'])} frames"]
    summary: dict = {"receiver": str(receiver_path), "attributes": {k: str(v) for k, v in attrs.items()}}
    if truth_frames is not None:
        acc = receiver_accuracy(frames, truth_frames)
        summary["accuracy"] = acc
        lines.append(f"- radial velocity RMSE (1 s means) {acc['velocity_rmse_1s_mps']:.3f} m/s; integrated range "
                     f"error 95 % {acc['range_error_p95_m']:.3f} m, max {acc['range_error_max_m']:.3f} m over "
                     f"{acc['seconds']:.1f} s")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return out


def check_report_inputs(results_path: str | os.PathLike, truth_path: str | os.PathLike | None,
                        receiver_only: bool = False) -> None:
    """The groups a report reads are there (ValueError naming the file and what is missing)."""
    if receiver_only:
        read_receiver_frames(results_path)
    else:
        with open_h5(results_path) as f:
            if schema.FUSION not in f or not len(f[schema.FUSION]):
                raise ValueError(f"{results_path}: no /{schema.FUSION} group (run 'dtmbnav fuse' or 'dtmbnav run' "
                                 "first)")
            for name in (schema.PDR, schema.RECEIVER_FRAMES):
                if name not in f:
                    raise ValueError(f"{results_path}: no /{name} group (not a results file of 'dtmbnav fuse')")
    if truth_path is not None:
        read_walk_truth(truth_path)
        read_columns(truth_path, schema.TRUTH_FRAMES)
        if not receiver_only:
            read_tower(truth_path)


def write_report_folder(results_path: str | os.PathLike, out_dir: str | os.PathLike,
                        truth_path: str | os.PathLike | None = None, receiver_only: bool = False,
                        origin: GeodeticPoint | None = None) -> Path:
    """``dtmbnav report``: the report of a results file (or of a receiver file alone) into ``out_dir``.

    ``origin`` places the results' ENU frame on WGS84 for the map files (``report --origin``), in place
    of the origin the results file holds.

    Written into a temporary folder and moved into ``out_dir`` only when
    complete (:func:`dtmbnav_core.h5io.atomic_folder`): a bad input leaves no
    half-written report.
    """
    from dtmbnav.chain.report import write_receiver_report, write_report

    check_report_inputs(results_path, truth_path, receiver_only)
    with atomic_folder(out_dir) as tmp:
        if receiver_only:
            write_receiver_report(results_path, tmp, truth_path=truth_path)
        else:
            write_report(results_path, tmp, truth_path=truth_path, origin=origin)
    return Path(out_dir)

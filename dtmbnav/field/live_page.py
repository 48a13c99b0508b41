"""The live web page: a small local HTTP server that shows a track and its stated error as it grows.

``dtmbnav live --web HOST:PORT`` starts one (:class:`LiveView`); a browser on the same machine or network opens
its address and sees the walk on a plain metric map (east right, north up, a grid whose spacing it states), every position's 95 %
error ellipse, the start fix, the direction of each tower, and the newest position in latitude and longitude
with its 95 % radius. The page needs no network beyond this server: no map tiles or script libraries are
fetched, so it works where a walker has no data connection.

The server is the standard library's :class:`http.server.ThreadingHTTPServer` on a daemon thread: two
routes and a JSON poll need no web framework. The page polls ``/state.json?since=N`` once a second and
receives only the rows after the N it already holds. Rows that revise earlier ones (a fusion that re-sends
the positions of a stretch once it can filter them) truncate the track at their first time and bump the
state's ``revision``, on which the page fetches the whole track again. The ``head`` is the stretch ahead of
the settled track (a now-cast past the last settled step), replaced at each update and drawn dashed.
"""

from __future__ import annotations

import json
import threading
from dataclasses import asdict, dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlparse

import numpy as np

from dtmbnav_core.records import ELLIPSE_95_CHI2

#: The page's file in this package.
PAGE_NAME = "live_page.html"


@dataclass(frozen=True)
class ViewScene:
    """What does not move: where the walk starts and where the towers are.

    Attributes
    ----------
    start_east_m, start_north_m : float
        The start fix in the local east/north frame, m.
    start_sigma_m : float
        Its stated one-sigma error per axis, m (NaN: none stated).
    tower_bearings_deg : list of float
        Bearing from the start to each tower, deg clockwise from north.
    tower_distances_m : list of float
        Distance from the start to each tower, m.
    """

    start_east_m: float
    start_north_m: float
    start_sigma_m: float = float("nan")
    tower_bearings_deg: list[float] = field(default_factory=list)
    tower_distances_m: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class ViewRow:
    """One position of the track as the page draws it.

    Attributes
    ----------
    t_s : float
        Walk time, s.
    east_m, north_m : float
        Position in the local east/north frame, m.
    lat_deg, lon_deg : float
        The same on WGS84, deg.
    ellipse_major_m, ellipse_minor_m : float
        Semi-axes of the stated 95 % error ellipse, m.
    ellipse_angle_deg : float
        Direction of the major axis, deg counter-clockwise from east.
    stage : str
        What the position rests on (``heading`` while the initial heading is not yet confident, then
        ``filtered``).
    """

    t_s: float
    east_m: float
    north_m: float
    lat_deg: float
    lon_deg: float
    ellipse_major_m: float
    ellipse_minor_m: float
    ellipse_angle_deg: float
    stage: str


def ellipse_95(var_x_m2: float, var_y_m2: float, cov_xy_m2: float) -> tuple[float, float, float]:
    """Semi-axes (m) and major-axis direction (deg counter-clockwise from east) of a covariance's 95 % ellipse."""
    values, vectors = np.linalg.eigh(np.array([[var_x_m2, cov_xy_m2], [cov_xy_m2, var_y_m2]]))
    major, minor = np.sqrt(ELLIPSE_95_CHI2 * np.maximum(values[::-1], 0.0))
    angle = np.degrees(np.arctan2(vectors[1, 1], vectors[0, 1]))
    return float(major), float(minor), float(angle)


def _finite_or_none(value: Any) -> Any:
    """JSON has no NaN: a non-finite float becomes null."""
    return value if not isinstance(value, float) or np.isfinite(value) else None


def _row_json(row: ViewRow) -> dict[str, Any]:
    return {key: _finite_or_none(value) for key, value in asdict(row).items()}


class _State:
    """The rows, scene and status the page polls, behind one lock (the live loop writes, the server reads)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.rows: list[dict[str, Any]] = []
        self.head: list[dict[str, Any]] = []
        self.revision = 0
        self.scene: dict[str, Any] | None = None
        self.status: dict[str, Any] = {}

    def snapshot(self, since: int) -> bytes:
        with self.lock:
            state = {"scene": self.scene, "status": self.status, "total": len(self.rows), "since": since,
                     "revision": self.revision, "rows": self.rows[since:], "head": self.head}
        return json.dumps(state, allow_nan=False).encode()


class LiveView:
    """A local web page that draws a growing track (module docstring).

    Parameters
    ----------
    host : str
        Address to listen on (``127.0.0.1``: this machine only; ``0.0.0.0``: the network too).
    port : int
        TCP port (0: any free one; :attr:`url` says which).

    Raises
    ------
    OSError
        The address cannot be bound (in use, not this machine's).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self._state = _State()
        self._page = resources.files(__package__).joinpath(PAGE_NAME).read_bytes()
        handler = _handler(self._state, self._page)
        self._server = ThreadingHTTPServer((host, port), handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, name="dtmbnav-live-page", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """The page's address."""
        host, port = self._server.server_address[:2]
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{port}/"

    def set_scene(self, scene: ViewScene) -> None:
        """Set the start fix and the towers."""
        with self._state.lock:
            self._state.scene = {key: _finite_or_none(value) for key, value in asdict(scene).items()}

    def set_status(self, **status: Any) -> None:
        """Replace the status line's fields (lock, SNR, clock offset, walk time, ...; plain JSON values)."""
        with self._state.lock:
            self._state.status = {key: _finite_or_none(value) for key, value in status.items()}

    def add_rows(self, rows: list[ViewRow]) -> None:
        """Append positions to the track; rows at or before the track's last time replace the track from there."""
        converted = [_row_json(row) for row in rows]
        if not converted:
            return
        with self._state.lock:
            held = self._state.rows
            if held and converted[0]["t_s"] <= held[-1]["t_s"]:
                keep = next(k for k, row in enumerate(held) if row["t_s"] >= converted[0]["t_s"])
                del held[keep:]
                self._state.revision += 1
            held.extend(converted)

    def set_head(self, rows: list[ViewRow]) -> None:
        """Replace the stretch drawn ahead of the track (module docstring)."""
        converted = [_row_json(row) for row in rows]
        with self._state.lock:
            self._state.head = converted

    @property
    def rows(self) -> int:
        """Positions held."""
        with self._state.lock:
            return len(self._state.rows)

    def close(self) -> None:
        """Stop serving."""
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _handler(state: _State, page: bytes) -> type[BaseHTTPRequestHandler]:
    """The request handler class serving ``page`` and ``state``."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            url = urlparse(self.path)
            if url.path in ("/", "/index.html"):
                self._send(page, "text/html; charset=utf-8")
            elif url.path == "/state.json":
                try:
                    since = max(int(parse_qs(url.query).get("since", ["0"])[0]), 0)
                except ValueError:
                    self.send_error(HTTPStatus.BAD_REQUEST, "since must be an integer")
                    return
                self._send(state.snapshot(since), "application/json")
            else:
                self.send_error(HTTPStatus.NOT_FOUND)

        def _send(self, body: bytes, content_type: str) -> None:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: Any) -> None:
            """Quiet: the terminal belongs to the live command's progress line."""

    return Handler

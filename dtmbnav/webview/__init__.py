"""The live web page: a small local HTTP server that shows a track and its stated error as it grows.

``dtmbnav live --web HOST:PORT`` starts one (:class:`LiveView`); a browser on the same machine or network opens
its address and sees the walk on a plain metric map (east right, north up, a scale bar), every position's 95 %
error ellipse, the start fix, the direction of each tower, and the newest position in latitude and longitude
with its 95 % radius. The page needs no network beyond this server: no map tiles or script libraries are
fetched, so it works where a walker has no data connection.

The server is the standard library's :class:`http.server.ThreadingHTTPServer` on a daemon thread: two
routes and a JSON poll need no web framework. The page polls ``/state.json?since=N`` once a second and
receives only the rows after the N it already holds.
"""

from dtmbnav.webview.server import LiveView, ViewRow, ViewScene

__all__ = ["LiveView", "ViewRow", "ViewScene"]

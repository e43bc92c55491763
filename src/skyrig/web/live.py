"""The page of ``skyrig live``: a Leaflet map (vendored from the npm registry, ``static/leaflet``, BSD-2-Clause) of
the live run's XYZ tiles (orthos and DSM) that grows as the tiles are written, with the exposures' latency and the
online boresight (from ``status.json``).

Same security as :class:`skyrig.web.server.MeasureServer` (127.0.0.1 only, random token on every request, host and
origin checks).  Routes::

    GET /                                   the page (HTML)
    GET /static/<name>                      vendored front-end files (fixed list)
    GET /api/status                         the run's status.json
    GET /tiles/<layer>/<z>/<x>/<y>.png      a tile (layer ortho or dsm; 404 until written)

Tiles are written by renaming complete files into place (:mod:`skyrig.io.xyz_tiles`), so a tile is served whole or
not at all; no URL names a file beyond the fixed layer names and integer indices.
"""

from __future__ import annotations

import json
from pathlib import Path

from skyrig.web.server import MeasureServer, base_handler, page_handlers

__all__ = ["LiveServer", "LIVE_STATIC"]

#: The only static files the live page's server hands out: name -> (package path under skyrig/web/static, type).
LIVE_STATIC = {
    "leaflet.js": ("leaflet/leaflet.js", "text/javascript"),
    "leaflet.css": ("leaflet/leaflet.css", "text/css"),
    "leaflet-LICENSE.txt": ("leaflet/LICENSE.txt", "text/plain"),
    "live.js": ("live.js", "text/javascript"),
}
LAYERS = ("ortho", "dsm")


class LiveServer(MeasureServer):
    """Serve the live run's folder ``out`` (``tiles/``, ``status.json``) on 127.0.0.1 (see :class:`MeasureServer`
    for ``start``/``stop``/``url``)."""

    def __init__(self, out: str | Path, port: int = 0, token: str | None = None, title: str = "skyrig live") -> None:
        super().__init__(None, port, token, title)  # type: ignore[arg-type]
        self.out = Path(out)

    def make_app(self):  # type: ignore[no-untyped-def]
        import tornado.web

        server = self
        Base = base_handler(self)
        Page, Static = page_handlers(self, Base, "live.html", LIVE_STATIC)

        class Status(Base):
            def get(self) -> None:
                p = server.out / "status.json"
                try:
                    st = json.loads(p.read_text(encoding="utf-8"))
                except (OSError, ValueError):
                    st = {"exposures": [], "n_done": 0, "zooms": None, "bounds_lonlat": None}
                self.json(st)

        class Tile(Base):
            def get(self, layer: str, z: str, x: str, y: str) -> None:
                if layer not in LAYERS:
                    raise tornado.web.HTTPError(404, "no such layer")
                p = server.out / "tiles" / layer / str(int(z)) / str(int(x)) / f"{int(y)}.png"
                try:
                    data = p.read_bytes()
                except OSError:
                    raise tornado.web.HTTPError(404, "no tile (yet)") from None
                self.set_header("Content-Type", "image/png")
                self.finish(data)

        return tornado.web.Application([
            (r"/", Page),
            (r"/static/([A-Za-z0-9_.-]+)", Static),
            (r"/api/status", Status),
            (r"/tiles/([a-z]{1,8})/([0-9]{1,2})/([0-9]{1,8})/([0-9]{1,8})\.png", Tile),
        ], compress_response=False, xsrf_cookies=False)

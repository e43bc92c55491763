"""The local web server of ``skyrig measure`` (tornado), routing the page's requests to a
:class:`skyrig.web.measure.MeasureSession`.

Security: the server listens on 127.0.0.1 only; every request must carry the session's random token (``?token=``
or the ``X-Skyrig-Token`` header; 403 otherwise); the ``Host`` header must name 127.0.0.1 / localhost at the
server's port (a DNS-rebinding page gets 403) and a request that states an ``Origin`` must come from the page's own
origin (403 otherwise).  No URL names a file: images are addressed by their index in the orientations and the
static files by a fixed list, so there is no path to traverse.

Routes (JSON unless stated; ``POST`` bodies are JSON)::

    GET  /                                  the page (HTML)
    GET  /static/<name>                     vendored front-end files (fixed list)
    GET  /api/points                        ground points (MeasureSession.points_summary)
    GET  /api/point/<name>                  a point's predictions, measurements, intersection
    GET  /api/image/<index>                 an image's name and tile-source geometry
    GET  /api/tile/<index>/<level>/<x>_<y>.jpg   a deep-zoom tile (JPEG)
    POST /api/propose   {point, image, column, row, method, search_px}   the refined position (search_px: the
                        search radius, a number of pixels in [0, 200]; 400 naming it otherwise)
    POST /api/accept    {point, image, column, row, method, refined, sigma_px}   store + save
    POST /api/delete    {point, image}
    POST /api/detect    {point, accept}      automatic targets around the predictions: {found, skipped (image, reason)}
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import re
import secrets
import threading
from importlib import resources
from urllib.parse import quote

from skyrig.errors import SkyrigError
from skyrig.web.measure import MeasureSession, search_radius

__all__ = ["MeasureServer", "STATIC"]

log = logging.getLogger(__name__)

#: The only static files the server hands out: name -> (package path under skyrig/web/static, content type).
STATIC = {
    "openseadragon.min.js": ("openseadragon/openseadragon.min.js", "text/javascript"),
    "openseadragon-LICENSE.txt": ("openseadragon/LICENSE.txt", "text/plain"),
    "measure.js": ("measure.js", "text/javascript"),
    "measure.css": ("measure.css", "text/css"),
}


def _static(name: str) -> bytes:
    return (resources.files("skyrig.web") / "static" / name).read_bytes()


def base_handler(server: "MeasureServer"):
    """The request handler every route of a skyrig page derives from: host, origin and token checks, no caching,
    JSON replies and errors (shared by :class:`MeasureServer` and :class:`skyrig.web.live.LiveServer`)."""
    import tornado.web

    class Base(tornado.web.RequestHandler):
        def prepare(self) -> None:
            host = self.request.host or ""
            if host not in server.allowed_hosts:
                raise tornado.web.HTTPError(403, "host not allowed")
            origin = self.request.headers.get("Origin")
            if origin is not None and origin not in server.allowed_origins:
                raise tornado.web.HTTPError(403, "origin not allowed")
            token = self.get_query_argument("token", None) or self.request.headers.get("X-Skyrig-Token", "")
            if not hmac.compare_digest(str(token).encode(), server.token.encode()):
                raise tornado.web.HTTPError(403, "token missing or wrong")

        def set_default_headers(self) -> None:
            self.set_header("Cache-Control", "no-store")
            self.set_header("X-Content-Type-Options", "nosniff")
            self.set_header("Referrer-Policy", "no-referrer")

        def json(self, obj: object) -> None:
            self.set_header("Content-Type", "application/json")
            self.finish(json.dumps(obj, allow_nan=False))

        def body(self) -> dict:
            try:
                b = json.loads(self.request.body or b"{}")
            except ValueError:
                raise tornado.web.HTTPError(400, "body is not JSON") from None
            if not isinstance(b, dict):
                raise tornado.web.HTTPError(400, "body is not a JSON object")
            return b

        async def run(self, fn, *args):
            try:
                return await asyncio.get_running_loop().run_in_executor(None, fn, *args)
            except KeyError as exc:
                raise tornado.web.HTTPError(404, str(exc.args[0] if exc.args else exc)) from None
            except (SkyrigError, ValueError, TypeError) as exc:
                self.set_status(400)
                self.json({"error": str(exc)})
                return None

        def write_error(self, status_code: int, **kwargs) -> None:
            exc = kwargs.get("exc_info", (None, None))[1]
            msg = getattr(exc, "log_message", None) or self._reason
            self.set_header("Content-Type", "application/json")
            self.finish(json.dumps({"error": msg}))

    return Base


def page_handlers(server: "MeasureServer", Base, page: str, static: dict[str, tuple[str, str]]):  # type: ignore[no-untyped-def]
    """The page (``page`` with the token and title filled in, a strict Content-Security-Policy) and the handler of
    its vendored files (``static``: URL name -> (package path, content type); any other name is a 404)."""
    import tornado.web

    class Page(Base):
        def get(self) -> None:
            html = _static(page).decode("utf-8")
            self.set_header("Content-Type", "text/html; charset=utf-8")
            self.set_header("Content-Security-Policy", "default-src 'self'; img-src 'self' data: blob:; "
                                                       "style-src 'self' 'unsafe-inline'; script-src 'self'")
            self.finish(html.replace("__TOKEN__", server.token).replace("__TITLE__", server.title))

    class Static(Base):
        def get(self, name: str) -> None:
            if name not in static:
                raise tornado.web.HTTPError(404, "no such file")
            path, ctype = static[name]
            self.set_header("Content-Type", ctype)
            self.finish(_static(path))

    return Page, Static


def _make_app(server: "MeasureServer"):
    import tornado.web

    session = server.session

    Base = base_handler(server)
    Page, Static = page_handlers(server, Base, "measure.html", STATIC)

    class Points(Base):
        async def get(self) -> None:
            out = await self.run(session.points_summary)
            if out is not None:
                self.json({"points": out, "operator": session.operator, "output": str(session.output),
                           "sigmas": session.sigmas.__dict__, "n_images": len(session.eo)})

    class Point(Base):
        async def get(self, name: str) -> None:
            out = await self.run(session.point_state, name)
            if out is not None:
                self.json(out)
                asyncio.get_running_loop().run_in_executor(None, session.prefetch, name)  # not awaited

    class Image(Base):
        async def get(self, index: str) -> None:
            k = int(index)
            if not 0 <= k < len(session.eo):
                raise tornado.web.HTTPError(404, "no such image")
            name = str(session.eo.image[k])
            pyr = await self.run(session.pyramid, name)
            if pyr is not None:
                self.json({"image": name, "index": k, **pyr.info()})

    class Tile(Base):
        async def get(self, index: str, level: str, x: str, y: str) -> None:
            from skyrig.web.tiles import TileNotFound

            k = int(index)
            if not 0 <= k < len(session.eo):
                raise tornado.web.HTTPError(404, "no such image")
            name = str(session.eo.image[k])

            def tile() -> bytes:
                return session.pyramid(name).tile_jpeg(int(level), int(x), int(y))

            try:
                data = await asyncio.get_running_loop().run_in_executor(None, tile)
            except TileNotFound as exc:
                raise tornado.web.HTTPError(404, str(exc)) from None
            except SkyrigError as exc:
                raise tornado.web.HTTPError(404, str(exc)) from None
            self.set_header("Content-Type", "image/jpeg")
            self.finish(data)

    class Post(Base):
        action = ""

        async def post(self) -> None:
            b = self.body()
            try:
                if self.action == "propose":
                    args = (b["point"], b["image"], float(b["column"]), float(b["row"]), b.get("method", "auto"),
                            search_radius(b.get("search_px", 0.0)))
                    fn = session.propose
                elif self.action == "accept":
                    sig = b.get("sigma_px")
                    args = (b["point"], b["image"], float(b["column"]), float(b["row"]), b.get("method", "click"),
                            bool(b.get("refined", False)), None if sig is None else float(sig))
                    fn = session.accept
                elif self.action == "delete":
                    args, fn = (b["point"], b["image"]), session.delete
                else:
                    args, fn = (b["point"], 3.0, bool(b.get("accept", False))), session.detect
            except KeyError as exc:
                raise tornado.web.HTTPError(400, f"bad request body: no field {exc.args[0]!r}") from None
            except (TypeError, ValueError) as exc:
                raise tornado.web.HTTPError(400, f"bad request body: {exc}") from None
            out = await self.run(fn, *args)
            if out is not None:
                self.json(out if isinstance(out, dict) else {"found": out})

    def post_route(name: str):
        return type(f"Post_{name}", (Post,), {"action": name})

    return tornado.web.Application([
        (r"/", Page),
        (r"/static/([A-Za-z0-9_.-]+)", Static),
        (r"/api/points", Points),
        (r"/api/point/([^/]+)", Point),
        (r"/api/image/([0-9]{1,9})", Image),
        (r"/api/tile/([0-9]{1,9})/([0-9]{1,2})/([0-9]{1,6})_([0-9]{1,6})\.jpg", Tile),
        *[(rf"/api/{a}", post_route(a)) for a in ("propose", "accept", "delete", "detect")],
    ], compress_response=False, xsrf_cookies=False)


class MeasureServer:
    """The server of a :class:`MeasureSession`, on 127.0.0.1 at ``port`` (0: any free port), in a thread of its
    own (:meth:`start`, :meth:`stop`; or ``with MeasureServer(...) as srv:``).  :attr:`url` is the page's address
    with the token."""

    def __init__(self, session: MeasureSession, port: int = 0, token: str | None = None,
                 title: str = "skyrig measure") -> None:
        self.session = session
        self.port = int(port)
        self.token = token or secrets.token_urlsafe(24)
        self.title = re.sub(r"[<>&\"']", "", title)
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    @property
    def allowed_hosts(self) -> set[str]:
        return {f"127.0.0.1:{self.port}", f"localhost:{self.port}"}

    @property
    def allowed_origins(self) -> set[str]:
        return {f"http://{h}" for h in self.allowed_hosts}

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def url(self) -> str:
        """The page's address with its token."""
        return f"{self.base}/?token={quote(self.token)}"

    def make_app(self):  # type: ignore[no-untyped-def]
        """The tornado application served (a subclass serves its own page)."""
        return _make_app(self)

    def start(self) -> "MeasureServer":
        """Bind 127.0.0.1 and serve in a background thread; returns when listening."""
        import tornado.httpserver
        import tornado.netutil

        socks = tornado.netutil.bind_sockets(self.port, address="127.0.0.1")
        self.port = socks[0].getsockname()[1]

        def run() -> None:
            loop = asyncio.new_event_loop()
            asyncio.set_event_loop(loop)
            self._loop = loop
            try:
                srv = tornado.httpserver.HTTPServer(self.make_app())
                srv.add_sockets(socks)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller of start()
                self._error = exc
                self._ready.set()
                return
            self._ready.set()
            try:
                loop.run_forever()
            finally:
                srv.stop()
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.close()

        self._thread = threading.Thread(target=run, name="skyrig-measure-server", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error
        log.info("measuring page at %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving (the session stays open: close it yourself)."""
        if self._loop is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10)
            self._thread = None

    def __enter__(self) -> "MeasureServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

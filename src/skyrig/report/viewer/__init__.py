"""A static HTML viewer for skyrig's textured 3D models (GLB), with three.js vendored as package data.

:func:`viewer_html` returns one self-contained page: three.js (``three/three.module.min.js``, version
:data:`THREE_VERSION` from the npm package ``three``, MIT licence in ``three/LICENSE``), its ``GLTFLoader`` and
``OrbitControls`` (and ``BufferGeometryUtils``, which the loader imports) are put into the page's import map as
``data:`` URLs, and the model as base64, so that the page works when opened from the file system (Chromium
refuses module scripts from ``file://`` URLs).  Without an inlined model the page fetches ``model.glb`` next to it
(then it needs an http server, e.g. ``python -m http.server``).

When the first frame is drawn the page sets on ``<body>``: ``data-loaded="1"``, ``data-triangles``,
``data-meshes``, ``data-textured`` and ``data-drawn-fraction`` (share of pixels that differ from the background);
``data-error`` on failure.  Tests read them with ``chromium --headless --dump-dom``.
"""

from __future__ import annotations

import base64
import html
import json
from importlib import resources
from pathlib import Path

from skyrig.io._text import PathLike, atomic_write

__all__ = ["THREE_VERSION", "viewer_html", "write_viewer", "find_chromium", "chromium_check"]

THREE_VERSION = "0.170.0"  # npm package "three" the files in three/ come from

_MODULES = {  # import-map name -> vendored file
    "three": "three.module.min.js",
    "three/addons/utils/BufferGeometryUtils.js": "BufferGeometryUtils.js",
    "three/addons/loaders/GLTFLoader.js": "GLTFLoader.js",
    "three/addons/controls/OrbitControls.js": "OrbitControls.js",
}


def _vendored(name: str) -> str:
    return (resources.files(__package__) / "three" / name).read_text(encoding="utf-8")


def _data_url(js: str) -> str:
    return "data:text/javascript;base64," + base64.b64encode(js.encode("utf-8")).decode("ascii")


def viewer_html(glb: bytes | None, *, title: str = "skyrig 3D model") -> str:
    """The viewer page, with the model ``glb`` inlined (None: the page fetches ``model.glb`` next to it)."""
    imports = {}
    for spec, fname in _MODULES.items():
        js = _vendored(fname)
        # relative imports cannot be resolved from a data: URL: name the module by its import-map key
        js = js.replace("'../utils/BufferGeometryUtils.js'", "'three/addons/utils/BufferGeometryUtils.js'")
        imports[spec] = _data_url(js)
    page = (resources.files(__package__) / "index.html").read_text(encoding="utf-8")
    glb64 = base64.b64encode(glb).decode("ascii") if glb else ""
    return (page.replace("__IMPORTMAP__", json.dumps({"imports": imports}))
            .replace("__THREE_VERSION__", THREE_VERSION)
            .replace("__TITLE__", html.escape(title))
            .replace("__GLB_BASE64__", glb64))


def write_viewer(path: PathLike, glb_path: PathLike | None, *, title: str = "skyrig 3D model") -> Path:
    """Write the viewer page to ``path`` (temporary file, then renamed), the GLB file ``glb_path`` inlined (None:
    the page loads ``model.glb`` from its folder)."""
    data = Path(glb_path).read_bytes() if glb_path is not None else None
    p = Path(path)
    with atomic_write(p) as fh:
        fh.write(viewer_html(data, title=title))
    return p


def find_chromium() -> str | None:
    """A Chromium / Chrome executable on PATH (or ``/usr/bin/chromium``), or None."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome"):
        p = shutil.which(name)
        if p:
            return p
    return "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None


def chromium_check(html_path: PathLike, *, screenshot: PathLike | None = None, chromium: str | None = None,
                   timeout_s: float = 90.0, window: tuple[int, int] = (900, 650)) -> dict:
    """Open a viewer page (a file, or an ``http(s)://`` URL) in headless Chromium (software WebGL) and wait until it
    reports the model drawn.

    Talks to the browser over the DevTools protocol on a pipe (``--remote-debugging-pipe``): navigates to the
    page, polls ``document.body.dataset`` until ``loaded == "1"`` or ``error`` is set, then optionally saves a PNG
    screenshot of the page.

    Returns
    -------
    dict
        The body's ``data-*`` attributes (``loaded``, ``triangles``, ``meshes``, ``textured``, ``drawnFraction``
        or ``error``) plus ``seconds`` and ``chromium`` (the browser version).

    Raises
    ------
    FileNotFoundError
        No Chromium.
    TimeoutError
        The page did not report within ``timeout_s``.
    """
    import os
    import subprocess
    import time

    exe = chromium or find_chromium()
    if not exe:
        raise FileNotFoundError("no Chromium / Chrome executable found")
    url = str(html_path) if str(html_path).startswith(("http://", "https://")) else Path(html_path).resolve().as_uri()
    r_cmd, w_cmd = os.pipe()  # we write commands -> browser fd 3
    r_out, w_out = os.pipe()  # browser fd 4 -> we read
    import tempfile

    profile = tempfile.mkdtemp(prefix="skyrig-chromium-")
    args = [exe, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-first-run", "--no-default-browser-check",
            "--disable-extensions", f"--user-data-dir={profile}", f"--window-size={window[0]},{window[1]}", "about:blank"]

    def child() -> None:  # the pipe ends to fds 3 and 4 (via fds >= 10, in case they are 3 or 4 already)
        import fcntl

        a, b = fcntl.fcntl(r_cmd, fcntl.F_DUPFD, 10), fcntl.fcntl(w_out, fcntl.F_DUPFD, 10)
        os.dup2(a, 3)
        os.dup2(b, 4)

    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            close_fds=False, preexec_fn=child)  # fds 3 and 4 set up in the child
    os.close(r_cmd)
    os.close(w_out)
    t0 = time.time()
    buf = b""
    next_id = [0]

    def send(method: str, params: dict | None = None, session: str | None = None) -> dict:
        next_id[0] += 1
        msg: dict = {"id": next_id[0], "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(w_cmd, json.dumps(msg).encode() + b"\0")
        return wait_reply(next_id[0])

    def wait_reply(mid: int) -> dict:
        nonlocal buf
        import select

        while True:
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                m = json.loads(raw)
                if m.get("id") == mid:
                    if "error" in m:
                        raise RuntimeError(f"DevTools: {m['error']}")
                    return m.get("result", {})
            left = timeout_s - (time.time() - t0)
            if left <= 0:
                raise TimeoutError(f"{url}: no answer from Chromium within {timeout_s:.0f} s")
            ready, _, _ = select.select([r_out], [], [], min(left, 1.0))
            if ready:
                chunk = os.read(r_out, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium closed the DevTools pipe")
                buf += chunk

    try:
        version = send("Browser.getVersion").get("product", "")
        targets = send("Target.getTargets")["targetInfos"]
        page = next(t["targetId"] for t in targets if t["type"] == "page")
        sid = send("Target.attachToTarget", {"targetId": page, "flatten": True})["sessionId"]
        send("Page.enable", session=sid)
        send("Page.navigate", {"url": url}, session=sid)
        state: dict = {}
        while time.time() - t0 < timeout_s:
            res = send("Runtime.evaluate", {"expression": "JSON.stringify(document.body ? Object.assign({}, "
                                            "document.body.dataset) : {})", "returnByValue": True}, session=sid)
            state = json.loads(res.get("result", {}).get("value") or "{}")
            if state.get("loaded") == "1" or state.get("error"):
                break
            time.sleep(0.25)
        else:
            raise TimeoutError(f"{url}: the page did not report the model loaded within {timeout_s:.0f} s ({state})")
        if screenshot is not None:
            shot = send("Page.captureScreenshot", {"format": "png"}, session=sid)
            with atomic_write(screenshot, "wb") as fh:
                fh.write(base64.b64decode(shot["data"]))
        state["seconds"] = round(time.time() - t0, 2)
        state["chromium"] = version
        try:
            send("Browser.close")
        except (RuntimeError, TimeoutError, OSError):
            pass
        return state
    finally:
        os.close(w_cmd)
        os.close(r_out)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        import shutil

        shutil.rmtree(profile, ignore_errors=True)

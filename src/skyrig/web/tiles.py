"""Deep-zoom tiles of an image, made on demand (OpenSeadragon's default tile source geometry).

Level ``L`` of ``0..max_level`` (``max_level = ceil(log2(max(width, height)))``) is the image scaled by
``2 ** (L - max_level)``; tile ``(x, y)`` of a level covers its pixels ``[x t, (x + 1) t) x [y t, (y + 1) t)``
(``t`` = :data:`TILE`, clipped at the level's edge).  A tile is read from the file window by window
(:class:`skyrig.io.image_windows.ImageWindows`): levels at half resolution or more straight from the full
resolution, coarser levels from one overview of the whole image (longer side at most :data:`OVERVIEW_MAX`,
read once per image with GDAL's reduced decoding), so that a 100-MP frame is never held whole.

A JPEG or PNG can only be decoded from its top, so a window near its bottom costs most of a full decode: for such
a file of more than :data:`COPY_ABOVE_PIXELS`, :meth:`TilePyramid.prepare` writes a tiled copy into the session's
cache folder in a background thread (a few seconds for 100 MP; copies one at a time) and the fine levels come
from it once written.  The copy is written from one whole decode of the file (OpenCV, about 0.4 s for 100 MP), and
until it is written the fine tiles are cut from that decode: the first fine tile of a never-opened image costs
about one decode, not the copy.  A decode is made once per image, by whichever comes first (the copy or a tile
request; the others wait for it); decodes are held in a small cache shared by all pyramids (at most
:data:`DECODED_SLOTS` images, least recently used dropped first, plus the one the copy is being written from) and
dropped as soon as the image's copy is written: in steady state no image is held whole.  While a tile request
decodes, the copy being written waits (between rows of blocks): the image the user looks at comes first.  The copy
is for display only; measurements are refined on the original file.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import TileNotFound  # noqa: F401 - re-exported (defined in skyrig.errors)
from skyrig.io.image_windows import ImageWindows

__all__ = ["TILE", "OVERVIEW_MAX", "TilePyramid", "TileNotFound"]

TILE = 256  # tile size, pixels of a level
OVERVIEW_MAX = 2048  # longer side of the overview coarse levels come from
COPY_ABOVE_PIXELS = 16_000_000  # JPEG / PNG files larger than this get a tiled copy for their fine levels
DECODED_SLOTS = 2  # whole decodes held while their tiled copies are written (module docstring)


_COPY_SLOTS = threading.Semaphore(1)  # tiled copies are written one at a time (each keeps a core busy)
_DECODED: OrderedDict[int, "TilePyramid"] = OrderedDict()  # pyramids holding a whole decode, least recent first
_DECODED_LOCK = threading.Lock()
_URGENT = threading.Condition()  # tile requests decoding now: the copy being written waits for them
_urgent_n = 0


def _hold_decoded(pyr: "TilePyramid") -> None:
    """``pyr`` holds a whole decode now: mark it most recent, drop the decodes beyond :data:`DECODED_SLOTS`."""
    with _DECODED_LOCK:
        _DECODED[id(pyr)] = pyr
        _DECODED.move_to_end(id(pyr))
        while len(_DECODED) > DECODED_SLOTS:
            _, old = _DECODED.popitem(last=False)
            old._decoded = None


def _drop_decoded(pyr: "TilePyramid") -> None:
    with _DECODED_LOCK:
        _DECODED.pop(id(pyr), None)
        pyr._decoded = None


def _urgent(delta: int) -> None:
    global _urgent_n
    with _URGENT:
        _urgent_n += delta
        _URGENT.notify_all()


def _yield_to_urgent() -> None:
    """The copy's pause between rows of blocks: wait while a tile request decodes (at most a few seconds)."""
    with _URGENT:
        _URGENT.wait_for(lambda: _urgent_n == 0, timeout=10.0)


class TilePyramid:
    """The deep-zoom pyramid of one image file (module docstring); tiles as JPEG bytes, cached (LRU)."""

    def __init__(self, windows: ImageWindows, cache_tiles: int = 256, copy_to: str | None = None) -> None:
        self.img = windows
        self._copy_to = copy_to if (windows.driver in ("JPEG", "PNG") and not windows.tiled
                                    and windows.width * windows.height > COPY_ABOVE_PIXELS) else None
        self._fine: ImageWindows | None = None
        self._copy_started = False
        self._copy_done = threading.Event()
        self._copy_error: BaseException | None = None
        self._decoded: NDArray | None = None  # a whole decode while the copy is written (module docstring)
        self._decode_lock = threading.Lock()
        self._decode_failed = False
        self.width, self.height = windows.width, windows.height
        self.max_level = max(int(math.ceil(math.log2(max(self.width, self.height, 1)))), 0)
        self._overview: tuple[NDArray, float] | None = None
        self._cache: OrderedDict[tuple[int, int, int], bytes] = OrderedDict()
        self._cache_n = cache_tiles
        self._lock = threading.Lock()
        self._stretch: tuple[float, float] | None = None

    def prepare(self) -> None:
        """Start writing the tiled copy of a large JPEG / PNG (module docstring) in the background, once."""
        with self._lock:
            if self._copy_to is None or self._copy_started:
                return
            self._copy_started = True

        def run() -> None:
            try:
                with _COPY_SLOTS:
                    a = self._decode(urgent=False)
                    self._fine = self.img.tiled_copy(self._copy_to, pixels=a, pause=_yield_to_urgent)
            except BaseException as exc:  # noqa: BLE001 - the fine levels then read the original
                self._copy_error = exc
            finally:
                self._copy_done.set()
                _drop_decoded(self)

        threading.Thread(target=run, name="skyrig-tiled-copy", daemon=True).start()

    def _fine_source(self) -> ImageWindows | NDArray:
        """Where full- and half-resolution tiles come from: the file itself, its tiled copy once written, until
        then the whole decode (module docstring)."""
        if self._copy_to is None:
            return self.img
        self.prepare()
        if not self._copy_done.is_set():
            a = self._decode(urgent=True)
            if a is not None:
                return a
        self._copy_done.wait()
        return self._fine if self._fine is not None else self.img

    def _decode(self, urgent: bool) -> NDArray | None:
        """The whole image as :meth:`ImageWindows.window` gives it (RGB or one band, as stored), decoded once by
        OpenCV and held (module docstring); None when the copy is written (unless the copy itself asks) or OpenCV
        cannot decode the file as GDAL reads it (then the copy streams the file and fine tiles wait for it).
        ``urgent``: a tile request (the copy being written pauses while it decodes)."""
        import cv2

        with self._decode_lock:
            a = self._decoded
            if a is None and not self._decode_failed and not (urgent and self._copy_done.is_set()):
                if urgent:
                    _urgent(+1)
                try:
                    a = cv2.imread(str(self.img.path), cv2.IMREAD_UNCHANGED)  # as stored: no EXIF rotation, any depth
                finally:
                    if urgent:
                        _urgent(-1)
                if a is not None and a.ndim == 3:
                    a = a[..., 2::-1] if self.img.bands >= 3 and a.shape[2] >= 3 else a[..., 0]  # BGR(A) -> RGB
                if a is None or a.shape[:2] != (self.height, self.width) or a.dtype != self.img.dtype:
                    self._decode_failed = True
                    return None
                if self._copy_done.is_set():  # written while decoding: the copy serves
                    return a
                self._decoded = a
            if a is not None:
                _hold_decoded(self)
            return a

    def close(self) -> None:
        if self._copy_started:
            self._copy_done.wait()
        _drop_decoded(self)
        if self._fine is not None:
            self._fine.close()

    def info(self) -> dict:
        """What the page's tile source needs."""
        return {"width": self.width, "height": self.height, "tileSize": TILE, "tileOverlap": 0, "minLevel": 0,
                "maxLevel": self.max_level}

    def _overview_array(self) -> tuple[NDArray, float]:
        if self._overview is None:
            s = min(1.0, OVERVIEW_MAX / max(self.width, self.height))
            ow, oh = max(1, round(self.width * s)), max(1, round(self.height * s))
            a = self.img.window(0, 0, self.width, self.height, ow, oh)
            self._overview = (a, ow / self.width)
        return self._overview

    def _to_8bit(self, a: NDArray) -> NDArray[np.uint8]:
        if a.dtype == np.uint8:
            return a
        if self._stretch is None:  # 16 bit: one stretch per image (0.1 .. 99.9 % of the overview)
            ov = self._overview_array()[0].astype(np.float64)
            lo, hi = np.percentile(ov, [0.1, 99.9])
            self._stretch = (float(lo), float(max(hi, lo + 1.0)))
        lo, hi = self._stretch
        return np.clip((a.astype(np.float64) - lo) * (255.0 / (hi - lo)) + 0.5, 0, 255).astype(np.uint8)

    def tile_array(self, level: int, x: int, y: int) -> NDArray[np.uint8]:
        """Pixels of tile ``(x, y)`` of ``level`` (``(h, w)`` or ``(h, w, 3)`` RGB, 8 bit)."""
        import cv2

        if not 0 <= level <= self.max_level:
            raise TileNotFound(f"level {level} outside 0..{self.max_level}")
        scale = 2.0 ** (level - self.max_level)
        lw, lh = math.ceil(self.width * scale), math.ceil(self.height * scale)
        x0, y0 = x * TILE, y * TILE
        if x < 0 or y < 0 or x0 >= lw or y0 >= lh:
            raise TileNotFound(f"tile {x}_{y} outside level {level} ({lw} x {lh} px)")
        tw, th = min(TILE, lw - x0), min(TILE, lh - y0)
        c0, r0 = x0 / scale, y0 / scale
        c1, r1 = min((x0 + tw) / scale, self.width), min((y0 + th) / scale, self.height)
        ov, s_ov = self._overview_array() if scale < 0.5 else (None, 0.0)
        if ov is not None and scale <= s_ov:  # coarser than the overview: from the overview
            a = ov[int(r0 * s_ov):max(int(math.ceil(r1 * s_ov)), int(r0 * s_ov) + 1),
                   int(c0 * s_ov):max(int(math.ceil(c1 * s_ov)), int(c0 * s_ov) + 1)]
            a = cv2.resize(a, (tw, th), interpolation=cv2.INTER_AREA)
        else:
            src = self._fine_source()
            ci0, ri0, ci1, ri1 = int(c0), int(r0), int(math.ceil(c1)), int(math.ceil(r1))
            if isinstance(src, np.ndarray):  # the whole decode: GDAL's averaging of the window, in OpenCV
                a = np.ascontiguousarray(src[ri0:ri1, ci0:ci1])
                if a.shape[:2] != (th, tw):
                    a = cv2.resize(a, (tw, th), interpolation=cv2.INTER_AREA)
            else:
                a = src.window(ci0, ri0, ci1 - ci0, ri1 - ri0, tw, th)
        return self._to_8bit(a)

    def tile_jpeg(self, level: int, x: int, y: int, quality: int = 90) -> bytes:
        """Tile ``(x, y)`` of ``level`` as JPEG bytes (cached)."""
        import cv2

        key = (level, x, y)
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        a = self.tile_array(level, x, y)
        if a.ndim == 3:
            a = a[..., ::-1]
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(a), [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise RuntimeError("OpenCV could not encode a tile")
        data = buf.tobytes()
        with self._lock:
            self._cache[key] = data
            while len(self._cache) > self._cache_n:
                self._cache.popitem(last=False)
        return data

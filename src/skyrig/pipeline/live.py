"""Near-real-time processing of a flight as it is recorded (``skyrig live FOLDER``; issue 35, paper 001's 3K chain).

The watched folder is laid out as a flight folder (``docs/formats/simulated_project.md``) that grows::

    FOLDER/rig.yaml           the rig (present from the start)
    FOLDER/trajectory.csv     GNSS/IMU trajectory, appended as it is recorded (complete lines are read)
    FOLDER/events.csv         camera events, appended as images are taken
    FOLDER/images/<image>     the images, written as they come off the cameras
    FOLDER/flight.end         (optional) written when the flight is over: the run finishes what it can and stops

For every exposure (all heads of one event id, e.g. the 3K triple) as soon as its images are complete and the
trajectory reaches past its time:

1. **direct georeferencing** (:func:`skyrig.georef.direct.direct_georeference`) with the rig as calibrated online
   so far;
2. **ortho tiles** per image: the image resampled straight onto the Web Mercator pixels of the XYZ tiles (layer
   ``ortho``) it touches at every zoom, over the reference surface (the DEM, else the plane at
   ``surface_height_m``): :func:`skyrig.dense.grid_rectify.rectify_onto_grid`, a coarser zoom from the image
   reduced by ``cv2.pyrDown``; the exposure's tiles composited in memory and written once
   (:func:`skyrig.io.xyz_tiles.paint_tiles`, with a cache of the tiles written last);
3. a **DSM tile** as soon as the exposure has a stereo partner (the exposure before or after it in the same strip,
   stereo head, e.g. nadir): :func:`skyrig.dense.surface.dense_surface` on the pair, coloured by height into layer
   ``dsm`` (in a worker thread: it may lag the orthos by a few exposures);
4. the **online boresight** (:mod:`skyrig.calibrate.online_boresight`, worker thread): features of the new images,
   guided matching against the recent exposures, and every ``window`` exposures a rig adjustment of the window
   with the boresights free; the combination of the windows so far calibrates the rig of later exposures.

Scheduling: each :meth:`LiveRun.poll` processes the newest ready exposure; older ready ones (the chain fell behind)
are caught up by later polls and painted beneath what the tiles hold (``caught_up`` in ``latency.jsonl``).  The
DSM and the online boresight run in worker threads at a lower priority (nice +5, +10 on Linux), the online
boresight fed in time order (a window is consecutive exposures).

Inputs are polled (``os.stat`` every ``poll_s``), not watched through inotify (``watchdog``): completion of a file
cannot be told from file-system events anyway (a camera or a copy tool writes in pieces, network shares deliver no
events), so an image counts as written when its size and time stay unchanged for ``settle_s`` and it decodes
whole (a PNG ends with its IEND chunk, a JPEG with its EOI marker); polling a few hundred names is negligible next
to the processing.

Bad input is said in one line each and skipped, the run goes on: an image that never completes (still changing or
truncated after ``image_timeout_s``), an event whose image does not come, an exposure past the end of a trajectory
that stopped (no new samples for ``trajectory_timeout_s``).

Outputs in OUT (default ``FOLDER/live``): ``tiles/<layer>/<z>/<x>/<y>.png`` (written atomically), ``latency.jsonl``
(one JSON line per exposure: seconds from the last image written to DG, ortho tiles, DSM tiles), ``boresight.jsonl``
(one line per window and the running estimate), ``status.json`` (for the page), ``summary.json`` at the end.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from skyrig._plain import plain
from skyrig.calibrate import online_boresight as ob
from skyrig.camera.frame import FrameCamera
from skyrig.dense.fusion import FusionConfig
from skyrig.dense.grid_rectify import rectify_onto_grid
from skyrig.dense.surface import DenseConfig, dense_surface
from skyrig.errors import SkyrigError
from skyrig.georef.direct import direct_georeference
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.io import xyz_tiles
from skyrig.match.features import FeatureConfig
from skyrig.io._text import atomic_write
from skyrig.io.events_csv import read_events_csv
from skyrig.io.images import read_image
from skyrig.io.rig_file import read_rig
from skyrig.io.trajectory_csv import read_trajectory_csv
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

__all__ = ["FlightPaths", "LiveConfig", "LiveRun", "image_complete", "run_live"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class FlightPaths:
    """Where a flight is recorded: the rig file (present from the start), the trajectory and events CSV files and
    the image folder (written as the flight goes), and the file whose appearance says the flight is over."""

    rig: Path
    trajectory: Path
    events: Path
    images: Path
    end: Path

    @classmethod
    def of_folder(cls, folder: str | os.PathLike[str]) -> "FlightPaths":
        """The layout of a watched flight folder (module docstring)."""
        f = Path(folder)
        return cls(f / "rig.yaml", f / "trajectory.csv", f / "events.csv", f / "images", f / "flight.end")


@dataclass(frozen=True)
class LiveConfig:
    """Options of a live run (times in seconds of wall clock, heights in the output CRS's ellipsoidal heights).

    ``dem_path``: a reference DEM (GeoTIFF, ellipsoidal heights of its CRS, e.g. a public 30 m DEM) the orthos are
    projected on and the online boresight's reference heights come from, with ``surface_sigma_m``; without one
    (and outside it) the plane at ``surface_height_m``.  ``crs``: output map CRS (projected, metres).
    ``window``: exposures per online adjustment (0: no online boresight); ``features``: SIFT features per image
    for its tie points (800: as many tie points survive the thinning to 2 per cell as with 1,500, at 0.55 x the
    matching time).  ``stereo_head``: the head whose
    consecutive images make the DSM pairs (None: the head closest to nadir).  ``zoom_levels``: tile levels below
    the finest (which matches the ortho cell)."""

    surface_height_m: float = 0.0
    surface_sigma_m: float = 5.0
    dem_path: str | None = None
    crs: str | None = None
    cell_m: float | None = None
    dsm: bool = True
    dsm_height_range_m: float = 150.0
    window: int = 8
    features: int = 800
    stereo_head: str | None = None
    zoom_levels: int = 4
    poll_s: float = 0.2
    settle_s: float = 0.3
    image_timeout_s: float = 20.0
    trajectory_timeout_s: float = 20.0
    trajectory_margin_s: float = 0.3
    idle_stop_s: float | None = None


def _nice(increment: int) -> None:
    """Lower the calling thread's scheduling priority (Linux: a thread is a task with its own nice value); a no-op
    where that is not supported."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, 0) + increment)
    except (AttributeError, OSError):
        pass


def _process_cpu() -> float:
    """CPU seconds of this process, every thread and the child processes waited for."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def image_complete(path: Path) -> tuple[bool, str]:
    """Whether an image file is whole: a PNG ends with its IEND chunk, a JPEG with EOI, a TIFF decodes; and why
    not."""
    suffix = path.suffix.lower()
    try:
        size = path.stat().st_size
        if size == 0:
            return False, "empty file"
        with open(path, "rb") as fh:
            fh.seek(max(size - 12, 0))
            tail = fh.read()
    except OSError as exc:
        return False, f"cannot be read ({exc.strerror or exc})"
    if suffix == ".png" and not tail.endswith(b"IEND\xaeB`\x82"):
        return False, "truncated PNG (no IEND chunk)"
    if suffix in (".jpg", ".jpeg") and not tail.rstrip(b"\x00").endswith(b"\xff\xd9"):
        return False, "truncated JPEG (no end-of-image marker)"
    return True, ""


def _complete_lines(path: Path) -> str | None:
    """The file's text up to its last newline (a line being written is left for the next poll)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    cut = data.rfind(b"\n")
    return None if cut < 0 else data[:cut + 1].decode("utf-8", errors="replace")


@dataclass
class _Image:
    name: str
    head: str
    seen_wall: float
    size: int = -1
    mtime: float = 0.0
    stable_since: float = 0.0
    written_wall: float | None = None  # file's modification time once complete
    array: NDArray | None = None
    failed: str = ""


@dataclass
class _Exposure:
    exposure: int
    time_s: float
    images: dict[str, _Image] = field(default_factory=dict)
    seen_wall: float = 0.0
    ready_wall: float | None = None
    state: str = "waiting"  # waiting, done, skipped
    record: dict[str, Any] = field(default_factory=dict)


class LiveRun:
    """One live run over a watched folder (:meth:`poll` once, :meth:`run` until the flight ends)."""

    def __init__(self, folder: str | os.PathLike[str] | FlightPaths, out: str | os.PathLike[str] | None = None,
                 config: LiveConfig = LiveConfig(), say: Callable[[str], None] | None = None) -> None:
        self.paths = folder if isinstance(folder, FlightPaths) else FlightPaths.of_folder(folder)
        self.folder = self.paths.events.parent
        self.out = Path(out) if out is not None else self.folder / "live"
        self.config = config
        self.say = say or (lambda line: logger.warning("%s", line))
        rig_path = self.paths.rig
        if not rig_path.is_file():
            raise SkyrigError(f"{rig_path}: no rig file (the live run needs it from the start)")
        self.rig_nominal: Rig = read_rig(rig_path)
        self.rig: Rig = self.rig_nominal
        self.cameras: dict[str, FrameCamera] = {h.camera.name: h.camera for h in self.rig_nominal}
        self.stereo_head = config.stereo_head or self._nadir_head()
        self.cross = [(self.stereo_head, h.name) for h in self.rig_nominal if h.name != self.stereo_head]
        self.trajectory: Trajectory | None = None
        self.events: CameraEvents | None = None
        self._traj_text: str | None = None
        self._ev_text: str | None = None
        self._traj_changed_wall = time.time()
        self.exposures: dict[int, _Exposure] = {}
        if not config.crs:
            raise SkyrigError("the live run needs an output map CRS (option: crs), e.g. EPSG:25832")
        self.frame: WorldFrame = WorldFrame.map(config.crs)
        self.map_crs: str = self.frame.crs or config.crs  # the output map CRS (a map frame always carries one)
        self.dem = None
        if config.dem_path:
            from skyrig.io.dem import read_dem
            self.dem = read_dem(config.dem_path)
            if self.dem.frame.crs != self.frame.crs:
                from skyrig.geodesy.crs import resolve_crs

                if resolve_crs(self.dem.frame.crs) != resolve_crs(self.map_crs):
                    raise SkyrigError(f"{config.dem_path}: the reference DEM must be in the output CRS {config.crs} "
                                      "(option: dem)")
        self._lock = threading.Lock()
        # the workers run below the ortho loop's priority (Linux: a nicer thread), the online boresight lowest
        self._dsm_pool = ThreadPoolExecutor(1, thread_name_prefix="skyrig-live-dsm", initializer=_nice,
                                            initargs=(5,))
        self._cal_pool = ThreadPoolExecutor(1, thread_name_prefix="skyrig-live-cal", initializer=_nice,
                                            initargs=(10,))
        self._pending: list[Future] = []
        # the stereo head's image of every exposure processed lately: exposure -> (time, EO row, image)
        self._stereo: dict[int, tuple[float, ExteriorOrientations, NDArray]] = {}
        self._cal_buf: dict[int, tuple[ExteriorOrientations, dict[str, NDArray]]] = {}
        self._cal_fed: set[int] = set()
        self._newest_done = -np.inf  # time of the newest exposure processed (older ones are caught up later)
        self._to_merc: Any = None
        self._tile_cache = xyz_tiles.TileCache(256)
        self._cal_cpu = 0.0  # CPU seconds of the online boresight's thread
        self._cpu0 = _process_cpu()
        self._features: dict[str, Any] = {}
        self._matches: dict[tuple[str, str], NDArray] = {}
        self._cal_eo: list[ExteriorOrientations] = []
        self._windows: list[ob.WindowEstimate] = []
        self.estimate = ob.BoresightEstimate()
        self._written: list[float] = []
        self._zooms: list[int] | None = None
        self._bounds_ll: list[float] | None = None
        self.reported: list[str] = []
        self._last_input_wall = time.time()
        (self.out / "tiles").mkdir(parents=True, exist_ok=True)
        for name in ("latency.jsonl", "boresight.jsonl"):
            (self.out / name).unlink(missing_ok=True)

    # ------------------------------------------------------------------------------------------ inputs
    def _nadir_head(self) -> str:
        best, name = -2.0, ""
        for h in self.rig_nominal:
            z = float((h.mounting @ np.array([0.0, 0.0, -1.0]))[2])  # viewing axis (camera -z), body z points down
            if z > best:
                best, name = z, h.name
        return name

    def _report(self, line: str) -> None:
        self.reported.append(line)
        self.say(line)

    def _read_table(self, path: Path, current: str | None, reader: Callable[[Path], Any], min_rows: int
                    ) -> tuple[str | None, Any]:
        text = _complete_lines(path)
        if text is None or text == current:
            return current, None
        if sum(1 for line in text.splitlines() if line.strip() and not line.startswith("#")) < 1 + min_rows:
            return current, None  # the column header and fewer rows than a reader takes
        snap = self.out / "_inputs" / path.name
        with atomic_write(snap, "w", newline="") as fh:
            fh.write(text)
        try:
            return text, reader(snap)
        except SkyrigError as exc:
            line = f"{path}: cannot be read ({exc}); waiting for more lines"
            if line not in self.reported:
                self._report(line)
            return text, None

    def _read_inputs(self, now: float) -> None:
        text, traj = self._read_table(self.paths.trajectory, self._traj_text, read_trajectory_csv, 2)
        if traj is not None:
            self._traj_text, self.trajectory = text, traj
            self._traj_changed_wall = now
            self._last_input_wall = now
        text, ev = self._read_table(self.paths.events, self._ev_text, read_events_csv, 1)
        if ev is not None:
            self._ev_text, self.events = text, ev
            self._last_input_wall = now
            for k in range(len(ev)):
                eid, name = int(ev.exposure_id[k]), str(ev.image_name[k])
                x = self.exposures.get(eid)
                if x is None:
                    x = self.exposures[eid] = _Exposure(eid, float(ev.time_s[k]), seen_wall=now)
                if name not in x.images:
                    x.images[name] = _Image(name, str(ev.head[k]), now)

    def _check_image(self, img: _Image, now: float) -> None:
        if img.written_wall is not None or img.failed:
            return
        p = self.paths.images / img.name
        try:
            st = p.stat()
        except OSError:
            if now - img.seen_wall > self.config.image_timeout_s:
                img.failed = "no image"
                self._report(f"event without an image: {img.name} (no {p} {self.config.image_timeout_s:g} s after "
                             "its event); skipped")
            return
        if (st.st_size, st.st_mtime) != (img.size, img.mtime):
            img.size, img.mtime, img.stable_since = st.st_size, st.st_mtime, now
            self._last_input_wall = now
        why = "size still changing"
        if now - img.stable_since >= self.config.settle_s:
            ok, why = image_complete(p)
            if ok:
                try:
                    img.array = read_image(p)
                    img.written_wall = st.st_mtime
                    return
                except SkyrigError as exc:
                    why = str(exc)
        if now - img.seen_wall > self.config.image_timeout_s:
            img.failed = why
            self._report(f"image never completed writing: {p} ({why}, {self.config.image_timeout_s:g} s after its "
                         "event); skipped")

    # ------------------------------------------------------------------------------------------ loop
    def poll(self) -> int:
        """Read what is new and process every exposure that is ready; returns how many were processed."""
        now = time.time()
        self._read_inputs(now)
        ready: list[tuple[_Exposure, list[_Image]]] = []
        for eid in sorted(self.exposures):
            x = self.exposures[eid]
            if x.state != "waiting":
                continue
            for img in x.images.values():
                self._check_image(img, now)
            if any(i.written_wall is None and not i.failed for i in x.images.values()):
                continue
            good = [i for i in x.images.values() if i.written_wall is not None]
            if not good:
                x.state = "skipped"
                continue
            if x.ready_wall is None:
                x.ready_wall = now
            t_end = self.trajectory.span[1] if self.trajectory is not None else -np.inf
            if x.time_s + self.config.trajectory_margin_s > t_end:
                if now - max(x.ready_wall, self._traj_changed_wall) > self.config.trajectory_timeout_s:
                    x.state = "skipped"
                    self._report(f"trajectory stopped: exposure {eid} at t={x.time_s:.3f} s is past its end "
                                 f"({t_end:.3f} s, no new samples for {self.config.trajectory_timeout_s:g} s); skipped")
                continue
            ready.append((x, good))
        done = 0
        if ready:  # the newest exposure first; the older ones ready now are caught up by the next polls
            x, good = max(ready, key=lambda r: r[0].time_s)
            self._process(x, good, waiting=len(ready) - 1)
            done = 1
        self._feed_calibration()
        self._write_status()
        return done

    def run(self, stop: threading.Event | None = None, max_wall_s: float | None = None, complete: bool = False
            ) -> dict[str, Any]:
        """Poll until ``FOLDER/flight.end`` exists (or the flight is ``complete`` already: a recorded flight) and
        nothing is waiting, ``stop`` is set, no input came for ``idle_stop_s`` or ``max_wall_s`` passed; then
        :meth:`finish`."""
        t0 = time.time()
        while True:
            busy = self.poll()
            now = time.time()
            waiting = any(x.state == "waiting" for x in self.exposures.values())
            if stop is not None and stop.is_set():
                break
            if (complete or self.paths.end.exists()) and not waiting and self._read_done():
                break
            if self.config.idle_stop_s is not None and now - self._last_input_wall > self.config.idle_stop_s:
                break
            if max_wall_s is not None and now - t0 > max_wall_s:
                break
            if not busy:
                time.sleep(self.config.poll_s)
        return self.finish()

    def _read_done(self) -> bool:
        return _complete_lines(self.paths.events) == self._ev_text

    # ------------------------------------------------------------------------------------------ processing
    def height_at(self, x: NDArray, y: NDArray) -> NDArray[np.float64]:
        """Reference surface heights (the DEM's, the plane's outside it)."""
        base = np.full(np.shape(x), self.config.surface_height_m, dtype=np.float64)
        if self.dem is None:
            return base
        h = self.dem.sample(x, y)
        return np.where(np.isfinite(h), h, base)

    def _footprint(self, eo: ExteriorOrientations, i: int
                   ) -> tuple[tuple[float, float, float, float], float, NDArray[np.float64]]:
        """Bounds (map CRS) of image ``i``'s footprint on the reference plane, its GSD at the image centre, and the
        nine points (corners, edge middles, centre) the bounds come from."""
        cam = self.cameras[str(eo.camera[i])]
        w, h = cam.width, cam.height
        px = np.array([[0, 0], [w / 2, 0], [w, 0], [w, h / 2], [w, h], [w / 2, h], [0, h], [0, h / 2],
                       [w / 2, h / 2]], dtype=np.float64)
        d = cam.rays_from_pixels(px) @ eo.rotation[i].T
        c = eo.centre[i]
        s = (self.config.surface_height_m - c[2]) / d[:, 2]
        if np.any(~(s > 0)):
            raise SkyrigError(f"image {eo.image[i]} does not look down onto the reference surface")
        xy = c[:2] + s[:, None] * d[:, :2]
        gsd = float(cam.gsd(np.linalg.norm(s[-1] * d[-1])))
        return (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max())), gsd, xy

    def _tiles_setup(self, eo: ExteriorOrientations, cell: float) -> None:
        if self._zooms is not None:
            return
        from skyrig.geodesy.crs import horizontal_crs, resolve_crs, transformer

        self._to_merc = transformer(horizontal_crs(resolve_crs(self.map_crs)), "EPSG:3857")
        ll = xyz_tiles.lonlat_bounds(self.map_crs, (eo.centre[0, 0] - 1, eo.centre[0, 1] - 1,
                                                      eo.centre[0, 0] + 1, eo.centre[0, 1] + 1))
        zmax = xyz_tiles.zoom_for_cell(cell, 0.5 * (ll[1] + ll[3]))
        self._zooms = list(range(max(zmax - self.config.zoom_levels, 0), zmax + 1))

    def _ortho_tiles(self, eo: ExteriorOrientations, i: int, image: NDArray, xy: NDArray[np.float64],
                     tiles: dict[tuple[int, int, int], NDArray[np.uint8]]) -> None:
        """Image ``i`` resampled straight onto the Web Mercator pixels of the tiles it touches at every zoom
        (:func:`skyrig.dense.grid_rectify.rectify_onto_grid`; a coarser zoom from the image reduced as many times
        by ``cv2.pyrDown``), composited over ``tiles`` (z, x, y) -> RGBA."""
        import cv2

        assert self._zooms is not None and self._to_merc is not None
        zmax = self._zooms[-1]
        mx, my = self._to_merc.transform(xy[:, 0], xy[:, 1])
        pad = 0.1 * max(np.ptp(mx), np.ptp(my))  # the reference surface is not the plane the footprint is on
        box = (np.min(mx) - pad, np.min(my) - pad, np.max(mx) + pad, np.max(my) + pad)
        T = xyz_tiles.TILE_PX
        cam = self.cameras[str(eo.camera[i])]
        level_img, reduced = image, 0
        for level, z in enumerate(sorted(self._zooms, reverse=True)):
            if reduced < level and min(level_img.shape[:2]) > 16:
                level_img, reduced = cv2.pyrDown(level_img), reduced + 1
            x0, y0, x1, y1 = xyz_tiles.tile_range(z, box)
            b = xyz_tiles.tile_bounds(z, x0, y0)
            rgba = rectify_onto_grid(level_img, eo, i, cam, "EPSG:3857", b[0], b[3], (b[2] - b[0]) / T,
                                     (x1 - x0 + 1) * T, (y1 - y0 + 1) * T, self.height_at,
                                     step=8 if z == zmax else 4, level=reduced)
            for ty in range(y0, y1 + 1):
                for tx in range(x0, x1 + 1):
                    new = rgba[(ty - y0) * T:(ty - y0 + 1) * T, (tx - x0) * T:(tx - x0 + 1) * T]
                    on = new[..., 3] > 0
                    if not on.any():
                        continue
                    old = tiles.get((z, tx, ty))
                    tiles[(z, tx, ty)] = new.copy() if old is None else np.where(on[..., None], new, old)

    def _process(self, x: _Exposure, good: list[_Image], waiting: int = 0) -> None:
        t_start, cpu0 = time.time(), time.thread_time()
        assert self.events is not None and self.trajectory is not None
        names = {i.name for i in good}
        rows = [k for k in range(len(self.events)) if str(self.events.image_name[k]) in names]
        ev = self.events.subset(rows)
        with self._lock:
            rig = self.rig
        eo = direct_georeference(self.trajectory, rig, ev, self.frame)
        t_dg = time.time()
        heads = eo.head
        assert heads is not None  # direct georeferencing names every image's head
        arrays: dict[str, NDArray] = {}
        for n in eo.image:
            a = next(i.array for i in good if i.name == str(n))
            assert a is not None  # only complete images reach _process
            arrays[str(n)] = a
        written = max(i.written_wall or 0.0 for i in good)
        self._written.append(written)
        # an exposure older than one already painted is caught up: painted beneath what is there (newest on top)
        caught_up = x.time_s < self._newest_done
        self._newest_done = max(self._newest_done, x.time_s)
        cell_used = None
        tiles: dict[tuple[int, int, int], NDArray[np.uint8]] = {}
        # the stereo (nadir) head painted last: on top where the heads overlap (least relief displacement)
        for i in sorted(range(len(eo)), key=lambda k: str(heads[k]) == self.stereo_head):
            bounds, gsd, xy = self._footprint(eo, i)
            cell = self.config.cell_m or gsd
            if str(heads[i]) == self.stereo_head or cell_used is None:
                cell_used = cell
            self._tiles_setup(eo, cell)
            self._ortho_tiles(eo, i, arrays[str(eo.image[i])], xy, tiles)
            self._grow_bounds(bounds)
        n_tiles = len(xyz_tiles.paint_tiles(self.out / "tiles", "ortho", tiles, under=caught_up,
                                            cache=self._tile_cache))
        t_ortho = time.time()
        rec = {"exposure": x.exposure, "time_s": x.time_s, "images": sorted(names),
               "written_wall": written, "dg_s": t_dg - written, "ortho_s": t_ortho - written,
               "queue_s": t_start - written, "cpu_s": time.thread_time() - cpu0, "cell_m": cell_used, "dsm_s": None,
               "dsm_exposures": None, "tiles": n_tiles, "caught_up": caught_up, "waiting": waiting}
        x.record = rec
        x.state = "done"
        # the DSM of the stereo pairs this exposure completes (with the exposure before and, when it was caught
        # up, the one after it in the same strip), in the DSM worker
        sel = [k for k in range(len(eo)) if str(heads[k]) == self.stereo_head]
        if sel:
            k = sel[0]
            self._stereo[x.exposure] = (x.time_s, eo.subset([k]), arrays[str(eo.image[k])])
            if self.config.dsm:
                before, after = self._neighbours(x)
                if before is not None and before.exposure in self._stereo:
                    self._pending.append(self._dsm_pool.submit(
                        self._dsm, x, (before.exposure, *self._stereo[before.exposure]),
                        (x.exposure, *self._stereo[x.exposure]), written, cell_used or 1.0))
                if after is not None and after.exposure in self._stereo:
                    self._pending.append(self._dsm_pool.submit(
                        self._dsm, after, (x.exposure, *self._stereo[x.exposure]),
                        (after.exposure, *self._stereo[after.exposure]), after.record.get("written_wall", written),
                        cell_used or 1.0))
            for old in [e for e in self._stereo if e not in self._recent(16)]:
                self._stereo.pop(old, None)
        if self.config.window > 0:
            self._cal_buf[x.exposure] = (eo, arrays)
        self._pending = [f for f in self._pending if not f.done()]
        with open(self.out / "latency.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(plain({k: v for k, v in rec.items() if k != "images"})) + "\n")

    def _recent(self, n: int) -> set[int]:
        """The ``n`` newest exposures processed."""
        done = sorted((e.time_s, e.exposure) for e in self.exposures.values() if e.state == "done")
        return {e for _, e in done[-n:]}

    def _flight_interval(self) -> float | None:
        """Median time between consecutive exposures of the flight (event times)."""
        t = np.diff(np.sort([e.time_s for e in self.exposures.values()]))
        return float(np.median(t)) if len(t) else None

    def _neighbours(self, x: _Exposure) -> tuple[_Exposure | None, _Exposure | None]:
        """The exposures just before and after ``x`` in time when they are of the same strip (no gap over 1.5
        intervals)."""
        med = self._flight_interval()
        if med is None:
            return None, None
        before = [e for e in self.exposures.values() if e.time_s < x.time_s]
        after = [e for e in self.exposures.values() if e.time_s > x.time_s]
        b = max(before, key=lambda e: e.time_s) if before else None
        a = min(after, key=lambda e: e.time_s) if after else None
        b = b if b is not None and x.time_s - b.time_s <= 1.5 * med else None
        a = a if a is not None and a.time_s - x.time_s <= 1.5 * med else None
        return b, a

    def _feed_calibration(self) -> None:
        """Hand the processed exposures to the online boresight in time order (a window is consecutive exposures),
        past the skipped ones; stop at the first still waiting."""
        if self.config.window <= 0:
            return
        for x in sorted(self.exposures.values(), key=lambda e: e.time_s):
            if x.exposure in self._cal_fed:
                continue
            if x.state == "waiting":
                break
            self._cal_fed.add(x.exposure)
            item = self._cal_buf.pop(x.exposure, None)
            if item is not None:
                self._pending.append(self._cal_pool.submit(self._calibrate, *item))

    def _wall_interval(self) -> float | None:
        """Median wall-clock time between consecutive exposures' last images (the rate they arrive at)."""
        w = np.diff(np.sort(self._written))
        return float(np.median(w)) if len(w) else None

    def _grow_bounds(self, b: tuple[float, float, float, float]) -> None:
        ll = list(xyz_tiles.lonlat_bounds(self.map_crs, b))
        if self._bounds_ll is None:
            self._bounds_ll = ll
        else:
            o = self._bounds_ll
            self._bounds_ll = [min(o[0], ll[0]), min(o[1], ll[1]), max(o[2], ll[2]), max(o[3], ll[3])]

    def _dsm(self, x: _Exposure, old: tuple[int, float, ExteriorOrientations, NDArray],
             new: tuple[int, float, ExteriorOrientations, NDArray], written: float, cell: float) -> None:
        """DSM tiles of the stereo pair ``old``, ``new`` (exposure, time, EO row, image of the stereo head),
        reported for ``x`` (the later exposure)."""
        old_id, _, eo_old, img_old = old
        new_id, _, eo_new, img_new = new
        cpu0 = time.thread_time()
        try:
            eo2 = _concat(eo_old, eo_new)
            imgs = [img_old, img_new]
            h0 = self.config.surface_height_m
            r = self.config.dsm_height_range_m
            b0 = self._footprint(eo_old, 0)[0]
            b1 = self._footprint(eo_new, 0)[0]
            area = (max(b0[0], b1[0]), max(b0[1], b1[1]), min(b0[2], b1[2]), min(b0[3], b1[3]))
            if area[0] >= area[2] or area[1] >= area[3]:
                return
            # one pair: every cell has at most one pair's support (the block default asks for two)
            cfg = DenseConfig(cell_m=2 * cell, cloud=False, fusion=FusionConfig(min_support=1))
            dsm, _, _ = dense_surface(eo2, self.cameras, lambda k: imgs[k], self.frame, (h0 - 0.2 * r, h0 + r),
                                      area=area, config=cfg)
            rgba = _height_colours(dsm.height, h0 - 0.2 * r, h0 + 0.5 * r)
            xyz_tiles.paint(self.out / "tiles", "dsm", rgba, dsm.grid.transform, self.map_crs,
                            (self._zooms or [])[:-1] or (self._zooms or []))
            now = time.time()
            # in exposure intervals after the exposure's last image was written (the flight's own rate)
            med = self._wall_interval() or float("nan")
            done_exposures = (now - written) / med if med > 0 else None
            x.record["dsm_s"] = now - written
            x.record["dsm_exposures"] = done_exposures
            x.record["dsm_cells"] = int(np.isfinite(dsm.height).sum())
            x.record["dsm_cpu_s"] = time.thread_time() - cpu0
            with open(self.out / "latency.jsonl", "a", encoding="utf-8") as fh:
                fh.write(json.dumps(plain({"exposure": x.exposure, "dsm_s": x.record["dsm_s"],
                                           "dsm_exposures": done_exposures,
                                           "dsm_cells": x.record["dsm_cells"],
                                           "dsm_cpu_s": x.record["dsm_cpu_s"]})) + "\n")
        except Exception as exc:  # noqa: BLE001 - one pair failing must not stop the flight
            self._report(f"DSM of exposure {new_id} with exposure {old_id} failed: {exc}")

    def _calibrate(self, eo: ExteriorOrientations, arrays: dict[str, NDArray]) -> None:
        cpu0 = time.thread_time()
        try:
            for n in eo.image:
                self._features[str(n)] = ob.features_of(arrays[str(n)], FeatureConfig(
                    max_size=None, max_features=self.config.features))
            self._cal_eo.append(eo)
            win = self.config.window
            if len(self._cal_eo) < win:
                return
            block = self._cal_eo
            self._cal_eo = []
            eo_w = block[0]
            for e in block[1:]:
                eo_w = _concat(eo_w, e)
            assert self.events is not None and self.trajectory is not None
            w = ob.estimate_window(eo_w, self.cameras, lambda i: self._features[str(eo_w.image[i])], self.trajectory,
                                   self.rig_nominal, self.events, self.height_at, self.config.surface_sigma_m,
                                   cross=self.cross, prefix=f"w{len(self._windows)}_")
            self._windows.append(w)
            est = ob.combine(self._windows)
            with self._lock:
                self.estimate = est
                self.rig = ob.rig_with_corrections(self.rig_nominal, est.correction)
            for n in eo_w.image:
                self._features.pop(str(n), None)
            line = {"window": len(self._windows), "exposures": list(w.exposures), "sigma0": w.sigma0,
                    "points": w.n_points, "height_points": w.n_height_points, "seconds": w.seconds,
                    "window_deg": {h: np.degrees(v) for h, v in w.correction.items()},
                    "window_sigma_deg": {h: np.degrees(np.sqrt(np.diag(c))) for h, c in w.covariance.items()},
                    "estimate_deg": {h: np.degrees(v) for h, v in est.correction.items()},
                    "estimate_sigma_deg": {h: np.degrees(est.sigma(h)) for h in est.correction},
                    "n_exposures": est.n_exposures}
            with open(self.out / "boresight.jsonl", "a", encoding="utf-8") as fh:
                fh.write(json.dumps(plain(line)) + "\n")
        except Exception as exc:  # noqa: BLE001 - a failed window must not stop the flight
            self._report(f"online boresight window failed: {exc}")
        finally:
            self._cal_cpu += time.thread_time() - cpu0

    # ------------------------------------------------------------------------------------------ outputs
    def _write_status(self) -> None:
        ex = [x.record | {"state": x.state} if x.record else {"exposure": x.exposure, "state": x.state}
              for x in sorted(self.exposures.values(), key=lambda e: e.exposure)]
        with self._lock:
            est = self.estimate
        st = {"bounds_lonlat": self._bounds_ll, "zooms": self._zooms, "exposures": ex[-50:],
              "n_done": sum(1 for x in self.exposures.values() if x.state == "done"),
              "n_skipped": sum(1 for x in self.exposures.values() if x.state == "skipped"),
              "reported": self.reported[-20:],
              "boresight_deg": {h: np.degrees(v) for h, v in est.correction.items()},
              "boresight_sigma_deg": {h: np.degrees(est.sigma(h)) for h in est.correction}}
        with atomic_write(self.out / "status.json") as fh:
            fh.write(json.dumps(plain(st)))

    def finish(self) -> dict[str, Any]:
        """Wait for the workers, write ``summary.json`` and return it."""
        self._dsm_pool.shutdown(wait=True)
        self._cal_pool.shutdown(wait=True)
        self._write_status()
        recs = [x.record for x in self.exposures.values() if x.record]
        interval = self._wall_interval()

        def stats(key: str) -> dict[str, float] | None:
            v = np.array([r[key] for r in recs if r.get(key) is not None], dtype=float)
            if not len(v):
                return None
            return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
                    "p95": float(np.percentile(v, 95)), "max": float(v.max()), "n": int(len(v))}

        est = self.estimate
        summary = {"exposures_done": len(recs),
                   "exposures_skipped": sum(1 for x in self.exposures.values() if x.state == "skipped"),
                   "exposure_interval_flight_s": self._flight_interval(),
                   "exposure_interval_s": interval, "ortho_latency_s": stats("ortho_s"),
                   "cell_m": stats("cell_m"), "dg_latency_s": stats("dg_s"), "ortho_cpu_s": stats("cpu_s"),
                   "dsm_latency_s": stats("dsm_s"), "dsm_latency_exposures": stats("dsm_exposures"),
                   "dsm_cpu_s": stats("dsm_cpu_s"),
                   "boresight_cpu_s_per_exposure": self._cal_cpu / len(recs) if recs else None,
                   "process_cpu_s_per_exposure": (_process_cpu() - self._cpu0) / len(recs) if recs else None,
                   "caught_up": sum(1 for r in recs if r.get("caught_up")),
                   "ortho_within_interval": (None if interval is None or not recs else
                                             bool(all(r["ortho_s"] <= interval for r in recs))),
                   "ortho_within_interval_fraction": (None if interval is None or not recs else
                                                      float(np.mean([r["ortho_s"] <= interval for r in recs]))),
                   "boresight_windows": est.n_windows, "boresight_exposures": est.n_exposures,
                   "boresight_deg": {h: np.degrees(v) for h, v in est.correction.items()},
                   "boresight_sigma_deg": {h: np.degrees(est.sigma(h)) for h in est.correction},
                   "zooms": self._zooms, "bounds_lonlat": self._bounds_ll, "reported": self.reported}
        with atomic_write(self.out / "summary.json") as fh:
            fh.write(json.dumps(plain(summary), indent=1))
        return summary


def _concat(a: ExteriorOrientations, b: ExteriorOrientations) -> ExteriorOrientations:
    from dataclasses import replace

    def cat(u: Any, v: Any) -> Any:
        return None if u is None or v is None else np.concatenate([u, v])

    return replace(a, image=np.concatenate([a.image, b.image]), camera=np.concatenate([a.camera, b.camera]),
                   centre=np.vstack([a.centre, b.centre]), rotation=np.concatenate([a.rotation, b.rotation]),
                   time_s=cat(a.time_s, b.time_s), head=cat(a.head, b.head), exposure=cat(a.exposure, b.exposure),
                   extra={k: np.concatenate([a.extra[k], b.extra[k]]) for k in a.extra if k in b.extra})


def _height_colours(height: NDArray, lo: float, hi: float) -> NDArray[np.uint8]:
    """RGBA of heights on OpenCV's 'turbo' colour map between ``lo`` and ``hi`` (alpha 0 where NaN)."""
    import cv2

    ok = np.isfinite(height)
    v = np.clip((np.where(ok, height, lo) - lo) / (hi - lo), 0, 1)
    rgb = cv2.applyColorMap((v * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    return np.dstack([rgb, np.where(ok, 255, 0).astype(np.uint8)])


def run_live(folder: str | os.PathLike[str], out: str | os.PathLike[str] | None = None,
             config: LiveConfig = LiveConfig(), stop: threading.Event | None = None,
             max_wall_s: float | None = None, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """:class:`LiveRun` over ``folder`` until the flight ends; the summary."""
    return LiveRun(folder, out, config, say).run(stop, max_wall_s)

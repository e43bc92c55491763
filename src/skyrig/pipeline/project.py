"""The project file ``project.yaml``: what a flight recorded, the output CRS, and the stages to run with their options.

``skyrig init FOLDER`` writes one (commented) from what it finds; ``skyrig run project.yaml`` runs its stages
(:mod:`skyrig.pipeline.run`).  Every path is relative to the project file's folder.  Unknown keys are errors;
every error names the file, the line and the key path (``stages.dsm.mode``)::

    format: skyrig-project        # required, with version 1
    version: 1
    name: my-flight
    crs: EPSG:25832               # output CRS of every product (projected, metres; a compound CRS for orthometric heights)
    geoid: null                   # geoid grid (path or PROJ name) for orthometric heights; null: ellipsoidal heights
    output: output                # where each stage publishes its folder (output/<stage>/ with manifest.json)
    inputs:
      images: [images]            # image folder(s)
      trajectory: trajectory.csv  # skyrig trajectory CSV or Applanix SBET
      events: events.csv          # camera events
      rig: rig.yaml               # rig file (cameras, lever arms, boresights)
      eo: null                    # an EO file instead of trajectory + events (image mode)
      cameras: []                 # camera / rig files for an EO file
      control: gcp/ground_points.csv
      check: gcp/check_points.csv
      measurements: [gcp/image_measurements.csv]   # measured image positions of the control / check points
      scale_bars: null            # scale bars CSV from,to,length_m[,sigma_m] (adjust-uav without GNSS)
      ties: null                  # tie points measured elsewhere (point,image,column,row) instead of a match stage
      laser: [scan.csv]           # a raw scan CSV with strips (+ trajectory, rig with a scanner) or LAS/LAZ files
    executor: {kind: auto, workers: null, scheduler: null}
    stages:                       # run in this order; a stage not listed is not run
      georef: {}
      match: {terrain_height: 80.0}
      block: {free: [boresight]}
      adjust: {}
      dsm: {heads: [nadir]}

A terrestrial / close-range set without GNSS (``skyrig adjust-uav --no-gps``): ``stages: {match: {}, adjust-uav:
{no_gps: true, datum: scale-bar}}`` with ``inputs.cameras`` (the start camera), ``inputs.scale_bars`` or
``inputs.control`` (+ ``check``, ``measurements``); ``inputs.ties`` replaces the match stage when the tie points
come from elsewhere.

The stages and their options are those of :data:`skyrig.pipeline.run.STAGES` (``skyrig run --list-stages``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from skyrig.errors import InputFormatError, OptionError, SkyrigError
from skyrig.geodesy.carried import is_local_text
from skyrig.io.rig_file import _Map, load_yaml_lines

from skyrig.pipeline.spec import ExecutorSpec, Option, Project, StageSpec

if TYPE_CHECKING:
    from skyrig.pipeline.run import Stage

__all__ = ["PROJECT_FORMAT", "Project", "StageSpec", "ExecutorSpec", "Option", "load_project", "parse_project",
           "Detected", "detect_inputs", "project_template"]

PROJECT_FORMAT = "skyrig-project"

_TOP = {"format", "version", "name", "crs", "geoid", "output", "inputs", "executor", "stages"}
_INPUT_FILES = ("trajectory", "events", "rig", "eo", "control", "check", "scale_bars", "ties")
_INPUT_LISTS = ("images", "cameras", "measurements", "laser")
_EXECUTOR = {"kind", "workers", "scheduler"}


def load_project(path: str | Path, registry: Mapping[str, Stage] | None = None, live: bool = False) -> Project:
    """Read and validate a project file (see the module docstring).

    Parameters
    ----------
    path
        The ``project.yaml``.
    registry
        The stages that may be listed (default :data:`skyrig.pipeline.run.STAGES`).
    live
        The flight is still to be recorded (``skyrig run --live``): the trajectory, the events and the image
        folders need not exist yet.

    Raises
    ------
    InputFormatError
        For anything the format does not allow (unknown key, missing file, wrong option type, a stage that
        needs an earlier stage's output that no listed stage produces), naming the file, line and key path.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "project.yaml"
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFormatError("no such project file (skyrig init FOLDER writes one)", p) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"cannot read the project file ({exc})", p) from None
    return parse_project(text, p, registry, live)


def parse_project(text: str, path: Path, registry: Mapping[str, Stage] | None = None, live: bool = False
                  ) -> Project:
    """:func:`load_project` on the text of a project file (``path`` names it in errors and anchors its paths)."""
    if registry is None:
        from skyrig.pipeline.run import STAGES

        registry = STAGES
    path = Path(path).absolute()
    doc = load_yaml_lines(text, path)
    lines: dict[str, int] = {}

    def err(message: str, m: _Map | None, key_path: str, key: str | None = None) -> InputFormatError:
        line = None
        if m is not None:
            line = m.key_lines.get(key, m.line) if key is not None else m.line
        return InputFormatError(message, path, line, key_path)

    def mapping(value: Any, parent: _Map | None, kp: str, key: str | None, allowed: set[str] | None,
                required: set[str] = set()) -> _Map:
        if value is None:
            value = _Map()
            value.line = parent.key_lines.get(key, parent.line) if parent is not None and key else 1
            value.key_lines = {}
        if not isinstance(value, _Map):
            raise err(f"expected a mapping, got {type(value).__name__}", parent, kp, key)
        for k, ln in value.key_lines.items():
            lines[f"{kp}.{k}" if kp else k] = ln
        if allowed is not None:
            for k in value:
                if k not in allowed:
                    raise err(f"unknown key {k!r} (allowed: {', '.join(sorted(allowed))})", value,
                              f"{kp}.{k}" if kp else k, k)
        for k in sorted(required):
            if k not in value:
                raise err(f"missing key {k!r}", value, f"{kp}.{k}" if kp else k)
        return value

    def text_of(m: _Map, key: str, kp: str, nullable: bool = True) -> str | None:
        v = m.get(key)
        if v is None and nullable:
            return None
        if not isinstance(v, str) or not v.strip():
            raise err(f"expected text, got {v!r}", m, kp, key)
        return v.strip()

    def file_of(m: _Map, key: str, kp: str, must_exist: bool = True, folder: bool = False) -> Path | None:
        v = text_of(m, key, kp)
        if v is None:
            return None
        q = Path(v).expanduser()
        q = q if q.is_absolute() else path.parent / q
        if must_exist and not (q.is_dir() if folder else q.is_file()):
            raise err(f"no such {'folder' if folder else 'file'}: {q}", m, kp, key)
        return q

    def files_of(m: _Map, key: str, kp: str, folder: bool = False, must_exist: bool = True) -> tuple[Path, ...]:
        v = m.get(key)
        if v is None:
            return ()
        if isinstance(v, str):
            v = [v]
        if not isinstance(v, list):
            raise err(f"expected a list of paths, got {v!r}", m, kp, key)
        out = []
        for i, item in enumerate(v):
            tmp = _Map({key: item})
            tmp.line, tmp.key_lines = m.line, {key: m.key_lines.get(key, m.line)}
            q = file_of(tmp, key, f"{kp}[{i}]", must_exist=must_exist, folder=folder)
            if q is not None:
                out.append(q)
        return tuple(out)

    top = mapping(doc, None, "", None, _TOP, {"format", "version", "crs", "stages"})
    if top.get("format") != PROJECT_FORMAT:
        raise err(f"expected format {PROJECT_FORMAT!r}, got {top.get('format')!r} (is this a skyrig project file?)",
                  top, "format", "format")
    if top.get("version") != 1:
        raise err(f"version {top.get('version')!r} is not supported (this skyrig reads version 1)", top, "version",
                  "version")
    crs = text_of(top, "crs", "crs")  # null: an orientation without GNSS in its model frame (checked with the stages)
    geoid = text_of(top, "geoid", "geoid")
    if crs is not None:
        try:
            from skyrig.geodesy.crs import check_metric_projected
            from skyrig.geodesy.frame import WorldFrame
            frame = WorldFrame.map(crs, geoid)  # a local ENU frame's text gives the CRS files carry for it
            check_metric_projected(frame.crs, "the project's output CRS")
            if frame.geoid:
                frame.projection  # noqa: B018  (the geoid grid must exist now, not after the match stage)
            if is_local_text(crs):  # every stage writes in the CRS files carry for it (its name says which frame)
                crs = str(frame.crs)
        except Exception as exc:  # CRSError, pyproj errors: the reason in words
            key = "geoid" if geoid and "geoid" in str(exc).lower() else "crs"
            raise err(f"not a usable CRS / geoid: {exc}", top, key, key) from None
    name = text_of(top, "name", "name") or path.parent.name
    out_txt = text_of(top, "output", "output") or "output"
    output = Path(out_txt).expanduser()
    output = output if output.is_absolute() else path.parent / output

    inp = mapping(top.get("inputs"), top, "inputs", "inputs", set(_INPUT_FILES) | set(_INPUT_LISTS))
    recorded = ("trajectory", "events") if live else ()  # written during a live run's flight
    files = {k: file_of(inp, k, f"inputs.{k}", must_exist=k not in recorded) for k in _INPUT_FILES}
    images = files_of(inp, "images", "inputs.images", folder=True, must_exist=not live)
    cameras = files_of(inp, "cameras", "inputs.cameras")
    measurements = files_of(inp, "measurements", "inputs.measurements")
    laser = files_of(inp, "laser", "inputs.laser")

    ex = mapping(top.get("executor"), top, "executor", "executor", _EXECUTOR)
    kind = ex.get("kind", "auto")
    if kind not in ("auto", "serial", "local"):
        raise err(f"expected auto, serial or local, got {kind!r}", ex, "executor.kind", "kind")
    workers = ex.get("workers")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise err(f"expected a positive whole number or null, got {workers!r}", ex, "executor.workers", "workers")
    executor = ExecutorSpec(kind, workers, text_of(ex, "scheduler", "executor.scheduler"))

    st = mapping(top.get("stages"), top, "stages", "stages", None)
    if not st:
        raise err("no stages listed (e.g. georef, match, block, adjust, dsm)", top, "stages", "stages")
    stages = []
    provided: dict[str, str] = {}
    for sname, sval in st.items():
        kp = f"stages.{sname}"
        if sname not in registry:
            raise err(f"unknown stage {sname!r} (known: {', '.join(registry)})", st, kp, sname)
        stage = registry[sname]
        opts_in = mapping(sval, st, kp, sname, set(stage.options))
        opts: dict[str, Any] = {}
        for oname, opt in stage.options.items():
            if oname in opts_in:
                try:
                    opts[oname] = opt.check(opts_in[oname])
                    if opt.kind == "file" and opts[oname] is not None:
                        f = path.parent / Path(opts[oname]).expanduser()
                        if not f.is_file():
                            raise ValueError(f"no such file: {f} (relative to the project file's folder)")
                except ValueError as exc:
                    raise err(str(exc), opts_in, f"{kp}.{oname}", oname) from None
            else:
                opts[oname] = opt.default
        for need in stage.requires:
            if not any(alt in provided for alt in need.split("|")):
                raise err(f"stage {sname!r} needs {need.replace('|', ' or ')} from an earlier stage; list a stage "
                          "that produces it before it", st, kp, sname)
        for kind_ in stage.provides:
            provided[kind_] = sname
        stages.append(StageSpec(sname, opts, st.key_lines.get(sname)))
        if crs is None and not (sname == "match" or (sname == "adjust-uav" and opts.get("no_gps"))):
            raise err(f"crs: null (no output CRS) is for an orientation without GNSS in its model frame; stage "
                      f"{sname!r} needs an output CRS: give one", top, "crs", "crs")
    project = Project(path, name, crs, geoid, output, images, files["trajectory"], files["events"], files["rig"],
                      files["eo"], cameras, files["control"], files["check"], measurements, executor, tuple(stages),
                      lines, files["scale_bars"], files["ties"], laser)
    for spec in project.stages:
        check = registry[spec.name].check
        if check is not None:
            problem = check(project, spec.options)
            if problem is not None:
                raise project.error(problem[1], problem[0])
    return project


# ------------------------------------------------------------------------------------------ skyrig init
_SKIP_DIRS = {"truth", "scene", "output", "outputs", "match", ".cache", "reference", "__pycache__"}
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


@dataclass
class Detected:
    """What :func:`detect_inputs` found in a folder (paths absolute) and what it could not decide, in words."""

    folder: Path
    images: list[Path] = field(default_factory=list)
    n_images: int = 0
    trajectory: Path | None = None
    events: Path | None = None
    rig: Path | None = None
    eo: Path | None = None
    control: Path | None = None
    check: Path | None = None
    measurements: list[Path] = field(default_factory=list)
    crs: str | None = None
    crs_source: str | None = None
    terrain_height: float | None = None
    heads: list[str] = field(default_factory=list)
    exif_gps: bool = False
    notes: list[str] = field(default_factory=list)
    #: every output CRS the inputs state, ``(crs, where)``, in the order init takes them (the first is ``crs``)
    crs_candidates: list[tuple[str, str]] = field(default_factory=list)
    laser: list[Path] = field(default_factory=list)  # a raw scan CSV or LAS/LAZ files
    laser_reference: Path | None = None  # a reference cloud (name with 'reference' / 'tls'): control of the strips


def _first_line(p: Path) -> str:
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            return fh.readline().strip()
    except OSError:
        return ""


def _column_row(p: Path) -> str:
    """The first line of a CSV that is neither blank nor a ``#`` comment (its column header)."""
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            for _ in range(40):
                line = fh.readline()
                if not line:
                    break
                if line.strip() and not line.lstrip().startswith("#"):
                    return line.strip()
    except OSError:
        pass
    return ""


def _looks_like_rig(p: Path) -> bool:
    """A YAML file that says it is a skyrig rig file, or has a top-level ``heads:`` key."""
    try:
        text = p.read_text(encoding="utf-8-sig", errors="replace")[:20000]
    except OSError:
        return False
    return "skyrig-rig" in text or any(line.startswith("heads:") for line in text.splitlines())


def _header_crs(p: Path) -> str | None:
    """The ``# crs:`` of a skyrig CSV (None when absent or not a map CRS)."""
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            for _ in range(12):
                line = fh.readline()
                if not line.startswith("#"):
                    break
                key, _, val = line[1:].partition(":")
                if key.strip() == "crs" and val.strip() and not val.strip().lower().startswith("ecef"):
                    return val.strip()  # a map CRS, or a local ENU frame (products in the CRS carrying it)
    except OSError:
        return None
    return None


def _side_car_table(p: Path) -> str:
    """The ``table`` a CSV's side-car ``NAME.csv.json`` states (``"skyrig-eo 1"``), "" without one."""
    from skyrig.io.table_meta import meta_path, read_table_meta

    if not meta_path(p).is_file():
        return ""
    side = read_table_meta(p)  # a side-car that is not a skyrig statement is refused, naming it
    return str((side or {}).get("table", ""))


def _side_car_crs(p: Path) -> str | None:
    """The map CRS or local ENU frame (its text ``local lat lon h``) a CSV's side-car states (None without a side-car
    or for ECEF)."""
    from skyrig.io.table_meta import frame_of_meta, meta_path, read_table_meta

    if not meta_path(p).is_file():
        return None
    frame = frame_of_meta(read_table_meta(p) or {}, p)
    if frame is not None and frame.kind == "local":
        return frame.to_text()
    return str(frame.crs) if frame is not None and frame.kind == "map" else None


def _same_horizontal_crs(a: str, b: str) -> bool:
    from skyrig.errors import CRSError
    from skyrig.geodesy.crs import horizontal_crs, resolve_crs

    try:
        return bool(horizontal_crs(resolve_crs(a)).equals(horizontal_crs(resolve_crs(b)), ignore_axis_order=True))
    except (CRSError, ValueError, TypeError):
        return a == b


def crs_disagreement(candidates: list[tuple[str, str]]) -> str | None:
    """Words listing the candidates when the output CRSs the inputs state differ in their horizontal CRS (None
    when they agree or there are fewer than two); geographic ones (a trajectory in EPSG:4979) are no candidates
    for the output CRS and are left out."""
    from skyrig.errors import CRSError
    from skyrig.geodesy.crs import horizontal_crs, resolve_crs

    projected = []
    for crs, where in candidates:
        try:
            if horizontal_crs(resolve_crs(crs)).is_geographic:
                continue
        except (CRSError, ValueError, TypeError):
            pass
        projected.append((crs, where))
    if len(projected) < 2 or all(_same_horizontal_crs(projected[0][0], c) for c, _ in projected[1:]):
        return None
    return "; ".join(f"{c} from {w}" for c, w in projected)


def detect_inputs(folder: str | Path) -> Detected:
    """Find the inputs of a flight in ``folder`` (and its sub-folders, two levels, skipping ``truth``, ``scene``,
    ``output``...): image folders, a trajectory (skyrig CSV or SBET), camera events, a rig file, an EO file,
    control / check points and their image measurements, by reading each candidate with skyrig's readers.

    The output CRS is taken from the trajectory's or EO file's header or side-car (``NAME.csv.json``), else the
    control points' CRS, else the UTM zone of the images' EXIF GPS (every stated one is kept in
    ``crs_candidates``: :func:`project_template` refuses, listing them, when they differ); the terrain height for
    guided matching from the control points."""
    from skyrig.io.image_read import read_image_metadata

    root = Path(folder).absolute()
    d = Detected(root)
    files: list[Path] = []
    dirs = [root]
    for depth in range(3):
        nxt = []
        for dd in dirs:
            try:
                entries = sorted(dd.iterdir())
            except OSError:
                continue
            for e in entries:
                if e.name.startswith(".") or e.name in _SKIP_DIRS:
                    continue
                if e.is_dir() and depth < 2:
                    nxt.append(e)
                elif e.is_file():
                    files.append(e)
        dirs = nxt
    by_dir: dict[Path, int] = {}
    for f in files:
        if f.suffix.lower() in _IMAGE_SUFFIXES and f.parent.name not in ("gcp", "control"):
            by_dir[f.parent] = by_dir.get(f.parent, 0) + 1
    big = [k for k, n in by_dir.items() if n >= 2]
    d.images = sorted(big)
    d.n_images = sum(by_dir[k] for k in big)
    found: dict[str, list[Path]] = {"trajectory": [], "events": [], "EO file": [], "rig file": []}
    for f in files:
        suf, first = f.suffix.lower(), _first_line(f)
        if suf in (".out", ".sbet") or (suf == ".csv" and (first.startswith("# skyrig-trajectory")
                                                           or _side_car_table(f).startswith("skyrig-trajectory"))):
            found["trajectory"].append(f)
        elif suf == ".csv" and first.startswith("# skyrig-events"):
            found["events"].append(f)
        elif suf == ".csv" and (first.startswith("# skyrig-eo") or _side_car_table(f).startswith("skyrig-eo")):
            found["EO file"].append(f)
        elif suf == ".csv" and first.startswith("# skyrig-raw-scan"):
            d.laser.append(f)
        elif suf in (".las", ".laz"):
            low = f.stem.lower()
            if any(w in low for w in ("reference", "tls")) and d.laser_reference is None:
                d.laser_reference = f
            else:
                d.laser.append(f)
        elif suf in (".yaml", ".yml") and f.name != "project.yaml":
            from skyrig.io.rig_file import read_rig

            if _looks_like_rig(f):  # a rig file that does not read is an error, not "no rig"
                text = f.read_text(encoding="utf-8-sig", errors="replace")
                laser_only = "scanners:" in text and not any(ln.startswith("heads:") for ln in text.splitlines())
                if not found["rig file"] and not laser_only:
                    d.heads = list(read_rig(f).heads)
                found["rig file"].append(f)
        elif suf == ".csv" and f.parent.name != "tie":
            header = _column_row(f).lower().replace(" ", "")
            if header.startswith("point,image,column,row") or header.startswith("point,image,x,y"):
                d.measurements.append(f)
            elif header.startswith("name,x,y,z"):
                low = f.stem.lower()
                if "check" in low and d.check is None:
                    d.check = f
                elif any(w in low for w in ("ground", "gcp", "control")) and d.control is None:
                    d.control = f
    for what, cands in found.items():
        if len(cands) > 1:
            raise InputFormatError(f"{len(cands)} {what}s found: {', '.join(str(c.relative_to(root)) for c in cands)};"
                                   " skyrig init does not choose: leave one in the folder, or write the project file's"
                                   " inputs by hand", root)
    first_of = {k: (v[0] if v else None) for k, v in found.items()}
    d.trajectory, d.events, d.eo, d.rig = (first_of["trajectory"], first_of["events"], first_of["EO file"],
                                           first_of["rig file"])
    if d.eo is not None and d.trajectory is not None:
        d.notes.append(f"both a trajectory and an EO file ({d.eo.name}): the trajectory is used (rig mode)")
        d.eo = None
    for src, what in ((d.trajectory, "trajectory"), (d.eo, "EO file")):
        if src is not None and src.suffix.lower() == ".csv":
            c = _header_crs(src)
            if c:
                d.crs_candidates.append((c, f"the {what}'s header ({src.name})"))
            else:
                c = _side_car_crs(src)
                if c:
                    d.crs_candidates.append((c, f"the {what}'s side-car ({src.name}.json)"))
    pts = None
    if d.control is not None:  # control points that do not read are refused (were left out with a note)
        from skyrig.io.points_csv import read_points_csv

        pts = read_points_csv(d.control)
        if pts.frame.kind == "map":
            d.crs_candidates.append((str(pts.frame.crs), f"the control points' CRS ({d.control.name})"))
    if d.crs_candidates:
        d.crs, d.crs_source = d.crs_candidates[0]
    if d.laser and d.crs is None:  # the horizontal CRS of a georeferenced laser cloud
        import laspy

        for q in d.laser:
            if q.suffix.lower() in (".las", ".laz"):
                with laspy.open(q) as fh:
                    c = fh.header.parse_crs()
                h = c.sub_crs_list[0] if c is not None and c.is_compound else c
                if h is not None and h.to_epsg():
                    d.crs, d.crs_source = f"EPSG:{h.to_epsg()}", f"the horizontal CRS of {q.name}"
                break
    if pts is not None and len(pts):
        import numpy as np

        d.terrain_height = round(float(np.median(pts.xyz[:, 2])), 1)
    images = [f for dd in d.images for f in sorted(dd.iterdir()) if f.suffix.lower() in _IMAGE_SUFFIXES]
    from skyrig.io.image_read import check_image_complete

    for f in images:  # a truncated JPEG decodes with a warning that names no file: refused here, by name
        check_image_complete(f)
    if d.images and d.trajectory is None and d.eo is None:
        metas = []
        for f in images:
            try:
                metas.append(read_image_metadata(f))
            except Exception as exc:
                d.notes.append(f"no EXIF read from {f.name} ({exc})")
        with_gps = [m for m in metas if m.has_gps and m.alt_m is not None]
        d.exif_gps = bool(with_gps)
        if with_gps and len(with_gps) < len(metas):
            names = sorted(m.name for m in metas if not (m.has_gps and m.alt_m is not None))
            d.notes.append(f"{len(names)} of {len(metas)} images have no EXIF GPS position ({', '.join(names[:10])}"
                           f"{' ...' if len(names) > 10 else ''}): they are left out of adjust-uav (a warning names each); "
                           "the other images keep the GNSS-supported block")
        if with_gps and d.crs is None:
            from skyrig.geodesy.statement import utm_frame

            m = with_gps[0]
            d.crs, d.crs_source = str(utm_frame(m.lat_deg, m.lon_deg).crs), "the UTM zone of the images' EXIF GPS"
        elif not with_gps and metas:
            d.notes.append("no image has an EXIF GPS position: adjust-uav without GNSS (no_gps)")
    if d.measurements and d.control is None:
        d.notes.append("image measurements found but no control points: left out")
        d.measurements = []
    return d


def _yaml_value(v: Any) -> str:
    import json

    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_yaml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return v if v and all(c.isalnum() or c in "-_./:+" for c in v) and not v[0].isdigit() else json.dumps(v)
    return repr(v)


def project_template(det: Detected, crs: str | None = None, geoid: str | None = None,
                     registry: Mapping[str, Stage] | None = None, base: str | Path | None = None) -> str:
    """The text of a commented ``project.yaml`` for what :func:`detect_inputs` found (every stage option listed,
    the ones init decided set, the others commented out with their defaults).  Paths are written relative to
    ``base``, the folder the project file goes to (default the detected folder).

    Raises
    ------
    InputFormatError
        When no output CRS is known (none given and none found in the inputs) or no stage can run.
    """
    if registry is None:
        from skyrig.pipeline.run import STAGES

        registry = STAGES
    if not crs:
        clash = crs_disagreement(det.crs_candidates)
        if clash:
            raise InputFormatError(f"the inputs state different output CRSs ({clash}): skyrig init does not choose; "
                                   "give one (option --crs)", det.folder)
    crs = crs or det.crs
    free = (not crs and det.images and not det.exif_gps and det.trajectory is None and det.eo is None
            and det.control is None)
    if not crs and not free:
        raise InputFormatError("no output CRS found in the inputs (trajectory / EO header, control points, EXIF "
                               "GPS): give one (option --crs)", det.folder)
    from skyrig.geodesy.crs import check_metric_projected
    from skyrig.geodesy.frame import WorldFrame

    try:
        if crs:
            frame = WorldFrame.map(crs, geoid)
            check_metric_projected(frame.crs, "the project's output CRS")
    except SkyrigError as exc:
        raise OptionError("--crs" if crs != det.crs else f"--crs (none given; {det.crs} from {det.crs_source})",
                          str(exc)) from None

    import os

    anchor = Path(base).absolute() if base is not None else det.folder

    def rel(q: Path | None) -> str:
        if q is None:
            return "null"
        r = os.path.relpath(q, anchor)
        return _yaml_value(str(q) if r.startswith(os.pardir + os.sep + os.pardir) else r)  # far away: absolute

    rig_mode = det.trajectory is not None and det.events is not None and det.rig is not None
    chosen: dict[str, dict[str, Any]] = {}
    if rig_mode:
        chosen["georef"] = {}
    if det.images:
        chosen["match"] = {"terrain_height": det.terrain_height} if (rig_mode or det.eo) else {}
    if det.images and (rig_mode or (det.eo is not None and det.rig is not None)):
        chosen["block"] = {"free": ["boresight"]} if rig_mode and det.control is not None else {}
        chosen["adjust"] = {}
    elif det.images and det.exif_gps and "adjust-uav" in registry:
        chosen["adjust-uav"] = {}
    elif det.images and det.eo is None and "adjust-uav" in registry:  # no GNSS at all: a terrestrial set
        chosen["adjust-uav"] = {"no_gps": True}
    # the dense stage needs camera files: a rig, or the self-calibrated camera adjust-uav publishes (camera.yaml)
    if det.images and chosen and ((det.rig is not None and (rig_mode or det.eo is not None))
                               or ("adjust-uav" in chosen and det.exif_gps)):
        chosen["dsm"] = {"heads": ["nadir"]} if "nadir" in det.heads else {}
        if not any(k in chosen for k in ("adjust", "adjust-uav")) and det.terrain_height is not None:
            chosen["dsm"]["height_range"] = [det.terrain_height - 50.0, det.terrain_height + 100.0]
        if "ortho" in registry:
            chosen["ortho"] = {"heads": ["nadir"]} if "nadir" in det.heads else {}
    if det.laser and "lidar" in registry:
        chosen["lidar"] = {"reference": rel(det.laser_reference).strip(chr(34))} if det.laser_reference is not None else {}
        if "dtm" in registry and "dtm" not in chosen:
            chosen["dtm"] = {}
    if not chosen:
        raise InputFormatError("found nothing to run: no images, no trajectory + events + rig, no laser data (skyrig "
                               "init looks for them in the folder and two levels of sub-folders)", det.folder)
    out = [f"# skyrig project file (written by skyrig init from {det.folder}).",
           "# Paths are relative to this file. Unknown keys are errors. Run it with: skyrig run project.yaml",
           "# A stage reruns only when its inputs or options change (its manifest keeps a fingerprint).",
           f"format: {PROJECT_FORMAT}", "version: 1", f"name: {_yaml_value(det.folder.name)}",
           f"crs: {_yaml_value(crs)}" + (f"    # from {det.crs_source}" if det.crs_source and crs == det.crs else
                                         "    # output CRS of every product (projected, metres)" if crs else
                                         "    # none: no GNSS and no control points in a map CRS, so the "
                                         "orientation is in a model frame (scale bars or a free network); give "
                                         "control points and a CRS to place it"),
           *([f"# crs is a local ENU frame: orientations and points read in it convert exactly; the products are "
              "written in the CRS files carry for it, the Local Orthographic projection at its origin on WGS 84 "
              "scaled to its height, with WGS 84 ellipsoidal heights (named 'skyrig local ENU ... carried as Local "
              "Orthographic'); each side-car states how far that is from ENU (docs/formats/local_frame.md)"]
             if crs and is_local_text(crs) else []),
           f"geoid: {_yaml_value(geoid)}    # geoid grid for orthometric heights; null: ellipsoidal heights "
           "(or those of a compound CRS)",
           "output: output    # each stage publishes output/<stage>/ with its manifest.json; output/run.json",
           "inputs:",
           f"  images: {_yaml_value([rel(q).strip(chr(34)) for q in det.images])}    # {det.n_images} images",
           f"  trajectory: {rel(det.trajectory)}    # skyrig trajectory CSV or Applanix SBET",
           f"  events: {rel(det.events)}    # camera events CSV",
           f"  rig: {rel(det.rig)}    # rig file" + (f" (heads: {', '.join(det.heads)})" if det.heads else ""),
           f"  eo: {rel(det.eo)}    # an EO file instead of trajectory + events (image mode)",
           "  cameras: []    # camera / rig files for an EO file",
           f"  control: {rel(det.control)}    # control points CSV (CRS in its header)",
           f"  check: {rel(det.check)}    # check points: compared after the adjustment, not used in it",
           f"  measurements: {_yaml_value([rel(q).strip(chr(34)) for q in det.measurements])}"
           "    # image positions of control / check points",
           "  scale_bars: null    # scale bars CSV from,to,length_m[,sigma_m] (adjust-uav with no_gps)",
           "  ties: null    # tie points measured elsewhere (point,image,column,row) instead of a match stage",
           f"  laser: {_yaml_value([rel(q).strip(chr(34)) for q in det.laser])}"
           "    # a raw scan CSV with strips (+ trajectory, rig with a scanner) or LAS/LAZ files",
           "executor:    # where parallel work runs; never changes the results",
           "  kind: auto    # auto | serial | local (Dask worker processes)",
           "  workers: null    # local worker processes (default: up to 4)",
           "  scheduler: null    # address of a dask.distributed scheduler, e.g. tcp://host:8786",
           "stages:    # run in this order; remove a stage to skip it"]
    for note in det.notes:
        out.insert(3, f"# note: {note}")
    for name, set_opts in chosen.items():
        stage = registry[name]
        out.append(f"  {name}:    # {stage.help}")  # options all commented out: the stage with its defaults
        for oname, opt in stage.options.items():
            if oname in set_opts:
                out.append(f"    {oname}: {_yaml_value(set_opts[oname])}    # {opt.help}")
            else:
                out.append(f"    # {oname}: {_yaml_value(opt.default)}    # {opt.help}")
    if "dsm" in chosen and "facades" in registry and set(det.heads) - {"nadir"}:
        out.append(f"  # facades: {{}}    # uncomment: {registry['facades'].help}")
    if "match" in chosen and chosen["match"].get("terrain_height", 0) is None:
        out.insert(3, "# note: set stages.match.terrain_height (mean terrain height, m): no control points to take it from")
    return "\n".join(out) + "\n"

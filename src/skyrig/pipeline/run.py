"""Project runs: the stages of a ``project.yaml`` (:mod:`skyrig.pipeline.project`) in order, each published into
its own folder ``OUTPUT/<stage>/`` as a set (:func:`skyrig.io.stage.stage_folder`, ``manifest.json`` last).

Resume
------
A stage's *fingerprint* is the SHA-256 of its options (defaults filled in), the project CRS / geoid, the content
(SHA-256) of the project files it reads, a listing (name, size, modification time) of the image folders it reads,
and the ``manifest.json`` of every earlier stage whose output it uses.  The fingerprint is stored in the stage's
manifest (``options.fingerprint``).  A stage is skipped when its folder is intact (every file as the manifest
lists it) and its fingerprint is unchanged; so a changed option reruns that stage, and - its manifest being new -
every stage that uses its output, nothing before it.  ``force`` reruns everything selected; ``from_stage`` reruns
that stage and those after it; ``only`` runs one stage (its inputs must have been published).  A failed or
interrupted stage publishes nothing: its previous folder and every earlier stage's stay as they were, and the
stages after it do not run.

Adding a stage
--------------
A stage is one :class:`Stage` entry in :data:`STAGES` (:func:`register_stage`): its name, a one-line help, its
options (:class:`skyrig.pipeline.project.Option`: default, type, help), what it needs from earlier stages
(``requires`` / ``uses``: kinds such as ``"eo"``, ``"points"``, ``"dsm"``), what it publishes (``provides``: kind
-> file name in its folder), which project files it reads (``inputs``) and the function that does the work::

    def _ortho(ctx: StageContext) -> dict:
        eo, dsm = ctx.need("eo"), ctx.need("dsm")          # files published by earlier stages
        run_ortho(eo, dsm, ..., ctx.out)                   # write into ctx.out (the staging folder)
        return {"tiles": 12}                               # a summary for run.json

    register_stage(Stage("ortho", "True orthophoto (COG) from the DSM and the oriented images.", _ortho,
                         options={"resolution": Option(None, "float", "cell size (m)", nullable=True)},
                         requires=("eo", "dsm"), provides={"ortho": "ortho.tif"}, inputs=_rig_files))

The function writes into ``ctx.out`` only; the runner publishes the folder and writes the manifest.  Every stage
calls the library function the command of the same name calls - :mod:`skyrig.pipeline.orientation` (``make_block``,
``make_adjustment``, ``make_uav_orientation``) and :mod:`skyrig.pipeline.products` (``make_dsm``, ``make_ortho``,
``make_facades``) - so its outputs are the command's, and nothing here imports :mod:`skyrig.cli`.  Errors:
:class:`skyrig.errors.SkyrigError` is bad input (exit status 2), :class:`StageError` says its status, anything else
is a failed run (exit status 1).  A failed adjustment (``adjust``, ``adjust-uav``) is a failed run; with the
stage option ``keep_failed`` its outputs are published with ``FAILED.txt``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from skyrig.errors import SkyrigError, StageError  # noqa: F401 - StageError re-exported (defined in skyrig.errors)
from skyrig.pipeline.spec import ExecutorSpec, Option, Project, StageSpec

logger = logging.getLogger(__name__)

__all__ = ["Stage", "StageContext", "StageError", "StageEvent", "RunResult", "STAGES", "register_stage",
           "run_project", "plan_run", "stage_fingerprint"]


@dataclass
class StageContext:
    """What a stage function gets.

    Attributes
    ----------
    project
        The project.
    spec
        The stage as listed (``spec.options``: every option with its default filled in).
    out
        The staging folder: write the outputs here (published as ``folder`` when the function returns).
    folder
        Where the outputs will be published (``OUTPUT/<stage>``).
    upstream
        Kind -> path of the file published by the latest earlier stage providing it (``requires`` and the
        ``uses`` that exist).
    progress
        ``progress(done, total)`` for the run's display.
    """

    project: Project
    spec: StageSpec
    out: Path
    folder: Path
    upstream: dict[str, Path]
    progress: Callable[[int, int], None] = lambda done, total: None

    @property
    def options(self) -> dict[str, Any]:
        return self.spec.options

    @property
    def executor(self) -> ExecutorSpec:
        return self.project.executor

    def need(self, kind: str) -> Path:
        """The file of ``kind`` published by an earlier stage (``KeyError`` naming it when there is none)."""
        if kind not in self.upstream:
            raise KeyError(f"stage {self.spec.name}: no earlier stage provides {kind!r}")
        return self.upstream[kind]

    def cache(self) -> Path:
        """A folder kept between runs for this stage's resumable work (``OUTPUT/.cache/<stage>``)."""
        p = self.project.output / ".cache" / self.spec.name
        p.mkdir(parents=True, exist_ok=True)
        return p


@dataclass(frozen=True)
class Stage:
    """A registry entry: everything the runner needs to know about one stage (see the module docstring)."""

    name: str
    help: str
    run: Callable[[StageContext], dict[str, Any] | None]
    options: dict[str, Option] = field(default_factory=dict)
    requires: tuple[str, ...] = ()  # kinds that must come from an earlier stage
    uses: tuple[str, ...] = ()  # kinds used when an earlier stage provides them
    provides: dict[str, str] = field(default_factory=dict)  # kind -> file in the stage's folder
    inputs: Callable[[Project, dict[str, Any]], list[Path]] = lambda project, options: []  # project files read
    check: Callable[[Project, dict[str, Any]], tuple[str, str] | None] | None = None  # (key path, problem) or None


#: Marker file in a stage folder published although the stage failed (``keep_failed``).
FAILED = "FAILED.txt"

#: The stages ``skyrig run`` knows, in their natural order (a project lists the ones it runs, in its order).
STAGES: dict[str, Stage] = {}


def register_stage(stage: Stage, registry: dict[str, Stage] | None = None) -> Stage:
    """Add ``stage`` to ``registry`` (default :data:`STAGES`); a name already taken is an error."""
    reg = STAGES if registry is None else registry
    if stage.name in reg:
        raise SkyrigError(f"stage {stage.name!r} is registered twice")
    reg[stage.name] = stage
    return stage


@dataclass(frozen=True)
class StageEvent:
    """What the runner reports as it goes: ``status`` is ``start``, ``progress``, ``done``, ``skipped``
    (up to date), ``not-selected`` (outside --from / --only), ``failed``."""

    stage: str
    status: str
    message: str = ""
    done: int | None = None
    total: int | None = None
    seconds: float | None = None


@dataclass
class RunResult:
    """The outcome of :func:`run_project`: per stage its status and seconds; ``exit_code`` 0 / 1 / 2."""

    project: Project
    stages: list[dict[str, Any]]
    exit_code: int = 0
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.exit_code == 0


# ------------------------------------------------------------------------------------------ fingerprints
def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _rel(project: Project, p: Path) -> str:
    try:
        return str(Path(os.path.abspath(p)).relative_to(Path(os.path.abspath(project.root))))
    except ValueError:
        return str(Path(os.path.abspath(p)))


def _folder_listing(folder: Path) -> str:
    """SHA-256 of the names, sizes and modification times (ns) of the files in ``folder`` (not recursive)."""
    rows = []
    for f in sorted(folder.iterdir()):
        if f.is_file():
            st = f.stat()
            rows.append(f"{f.name}\t{st.st_size}\t{st.st_mtime_ns}")
    return _sha("\n".join(rows).encode())


def stage_fingerprint(project: Project, stage: Stage, spec: StageSpec, upstream_folders: Mapping[str, Path]
                      ) -> tuple[list[dict[str, Any]], dict[str, Any], str]:
    """``(inputs, options, fingerprint)`` of a stage: the inputs as the manifest lists them, the options it
    records, and the SHA-256 over both (paths relative to the project folder, so a moved project resumes)."""
    from skyrig.io.stage import MANIFEST, sha256_file

    inputs: list[dict[str, Any]] = []
    for p in stage.inputs(project, spec.options):
        p = Path(p)
        if p.is_dir():
            inputs.append({"path": str(p.resolve()), "listing_sha256": _folder_listing(p)})
        elif p.is_file():
            inputs.append({"path": str(p.resolve()), "size": p.stat().st_size, "sha256": sha256_file(p)})
        else:
            inputs.append({"path": str(p.resolve()), "missing": True})
    for up_stage, folder in sorted(upstream_folders.items()):
        m = folder / MANIFEST
        inputs.append({"path": str(m.resolve()), "stage": up_stage, "sha256": sha256_file(m)})
    options = {"stage_options": spec.options, "crs": project.crs, "geoid": project.geoid}
    key = {"stage": stage.name, "options": options,
           "inputs": [{**{k: v for k, v in i.items() if k != "path"}, "path": _rel(project, Path(i["path"]))}
                      for i in inputs]}
    fp = _sha(json.dumps(key, sort_keys=True, default=str).encode())
    return inputs, dict(options, fingerprint=fp), fp


def _upstream(project: Project, registry: Mapping[str, Stage], index: int) -> tuple[dict[str, Path], dict[str, Path]]:
    """For the stage at ``index``: kind -> published file, and stage name -> folder, of the latest earlier
    stages providing what it requires / uses."""
    stage = registry[project.stages[index].name]
    files: dict[str, Path] = {}
    folders: dict[str, Path] = {}
    for need in (*stage.requires, *stage.uses):
        for kind in need.split("|"):  # "dsm|laser": the first kind an earlier stage provides
            for spec in reversed(project.stages[:index]):
                prov = registry[spec.name].provides
                if kind in prov:
                    folder = project.output / spec.name
                    files[kind] = folder / prov[kind]
                    folders[spec.name] = folder
                    break
            if kind in files:
                break
    return files, folders


def _up_to_date(folder: Path, fingerprint: str) -> tuple[bool, str]:
    from skyrig.io.stage import MANIFEST, read_manifest, verify_folder

    if not (folder / MANIFEST).is_file():
        return False, "not run yet"
    try:
        m = read_manifest(folder)
    except (OSError, ValueError):
        return False, "manifest unreadable"
    if m.get("options", {}).get("fingerprint") != fingerprint:
        return False, "inputs or options changed"
    if (folder / FAILED).is_file():
        return False, "its last run failed (outputs kept)"
    problems = verify_folder(folder)
    if problems:
        return False, f"outputs changed since ({problems[0]})"
    return True, "up to date"


# ------------------------------------------------------------------------------------------ the runner
def _selection(project: Project, from_stage: str | None, only: str | None) -> tuple[int, int]:
    names = [s.name for s in project.stages]
    for what, opt in ((from_stage, "--from"), (only, "--only")):
        if what is not None and what not in names:
            raise SkyrigError(f"{opt} {what}: the project lists no such stage (stages: {', '.join(names)})")
    if from_stage and only:
        raise SkyrigError("--from and --only exclude each other")
    if only:
        i = names.index(only)
        return i, i + 1
    return (names.index(from_stage) if from_stage else 0), len(names)


def plan_run(project: Project, *, from_stage: str | None = None, only: str | None = None, force: bool = False,
             registry: Mapping[str, Stage] | None = None) -> list[tuple[str, str, str]]:
    """What :func:`run_project` would do, without doing it: ``(stage, action, reason)`` with action ``run``,
    ``skip`` or ``not-selected``.  A stage after one that will run is listed as ``run`` (its input changes)."""
    reg = STAGES if registry is None else registry
    lo, hi = _selection(project, from_stage, only)
    out = []
    rerun: set[str] = set()
    for i, spec in enumerate(project.stages):
        files, folders = _upstream(project, reg, i)
        if not lo <= i < hi:
            out.append((spec.name, "not-selected", ""))
            continue
        if force or from_stage or only:
            out.append((spec.name, "run", "forced" if force else ("--only" if only else "--from")))
            rerun.add(spec.name)
            continue
        if any(s in rerun for s in folders):
            out.append((spec.name, "run", "an earlier stage it uses reruns"))
            rerun.add(spec.name)
            continue
        if not all((f / "manifest.json").is_file() for f in folders.values()):
            out.append((spec.name, "run", "not run yet"))
            rerun.add(spec.name)
            continue
        _, _, fp = stage_fingerprint(project, reg[spec.name], spec, folders)
        ok, why = _up_to_date(project.output / spec.name, fp)
        out.append((spec.name, "skip" if ok else "run", why))
        if not ok:
            rerun.add(spec.name)
    return out


def run_project(project: Project, *, from_stage: str | None = None, only: str | None = None, force: bool = False,
                registry: Mapping[str, Stage] | None = None,
                on_event: Callable[[StageEvent], None] | None = None) -> RunResult:
    """Run the project's stages (see the module docstring); never raises for a failing stage.

    Parameters
    ----------
    project
        From :func:`skyrig.pipeline.project.load_project`.
    from_stage
        Rerun this stage and every one after it; the earlier ones are not run (their outputs must exist).
    only
        Run only this stage (its inputs must have been published by an earlier run).
    force
        Rerun every selected stage even when it is up to date.
    registry
        The stages (default :data:`STAGES`).
    on_event
        Called with a :class:`StageEvent` as stages start, progress, finish, are skipped or fail.

    Returns
    -------
    RunResult
        Per stage ``{"stage", "status", "seconds", "reason", "summary"}``; ``exit_code`` 0 when every selected
        stage is up to date or ran, 2 when a stage found bad input, 1 when a stage failed.  ``OUTPUT/run.json``
        holds the same (written atomically).
    """
    from skyrig.io.report_html import project_stage
    from skyrig.io.stage import MANIFEST, stage_folder

    reg = STAGES if registry is None else registry
    emit = on_event or (lambda ev: None)
    lo, hi = _selection(project, from_stage, only)
    rows: list[dict[str, Any]] = []
    result = RunResult(project, rows)
    t_run = time.time()
    for i, spec in enumerate(project.stages):
        stage = reg[spec.name]
        folder = project.output / spec.name
        if not lo <= i < hi:
            rows.append({"stage": spec.name, "status": "not-selected"})
            emit(StageEvent(spec.name, "not-selected"))
            continue
        files, folders = _upstream(project, reg, i)
        missing = [s for s, f in folders.items() if not (f / MANIFEST).is_file()]
        missing += [k for k in stage.requires if not any(a in files for a in k.split("|"))]
        if missing:
            msg = (f"needs the output of stage {missing[0]}, which has not been published "
                   f"(run the earlier stages first: skyrig run without --from / --only)")
            rows.append({"stage": spec.name, "status": "failed", "reason": msg})
            emit(StageEvent(spec.name, "failed", msg))
            result.exit_code, result.error = 2, f"stage {spec.name}: {msg}"
            break
        files = {k: p for k, p in files.items() if p.exists() or any(k in r.split("|") for r in stage.requires)}
        inputs, options, fp = stage_fingerprint(project, stage, spec, folders)
        if not (force or from_stage or only):
            ok, why = _up_to_date(folder, fp)
            if ok:
                rows.append({"stage": spec.name, "status": "skipped", "reason": why})
                emit(StageEvent(spec.name, "skipped", why))
                continue
        else:
            why = "forced" if force else ("--only" if only else "--from")
        emit(StageEvent(spec.name, "start", why))
        t0 = time.perf_counter()

        def progress(done: int, total: int, _name: str = spec.name) -> None:
            emit(StageEvent(_name, "progress", done=done, total=total))

        said: list[str] = []  # the stage's warnings, in words, for run.json (the command line shows them as they come)
        try:
            with _warnings_into(said), stage_folder(folder, stage=spec.name, inputs=inputs, options=options,
                                                    started=t_run) as tmp:
                with project_stage(project.path, tmp, folder):  # its report names the project in words
                    summary = stage.run(StageContext(project, spec, tmp, folder, files, progress)) or {}
                if said and (tmp / "report.html").is_file():  # the stage's warnings on its page too
                    _report_warnings(tmp / "report.html", said)
                if summary.get("failed"):  # published as kept, never taken as up to date
                    (tmp / FAILED).write_text(f"stage {spec.name} failed: {summary['failed']}\n")
                absent = [f for f in stage.provides.values() if not (tmp / f).exists()]
                if absent:
                    raise StageError(spec.name, f"published no {absent[0]} (a stage bug)", 1)
        except StageError as exc:
            code, msg = exc.exit_code, exc.reason
        except SkyrigError as exc:
            code, msg = 2, str(exc)
        except KeyboardInterrupt:
            rows.append({"stage": spec.name, "status": "interrupted", **({"warnings": said} if said else {})})
            emit(StageEvent(spec.name, "failed", "interrupted"))
            result.exit_code, result.error = 130, f"stage {spec.name}: interrupted"
            _write_run_json(result)
            raise
        except Exception as exc:  # a bug or an unforeseen failure: the stage fails, the run says so
            logger.debug("stage %s failed", spec.name, exc_info=True)
            code, msg = 1, f"{type(exc).__name__}: {exc}"
        else:
            dt = time.perf_counter() - t0
            if not summary.get("failed"):
                rows.append({"stage": spec.name, "status": "done", "reason": why, "seconds": round(dt, 3),
                             "summary": summary, **({"warnings": said} if said else {})})
                emit(StageEvent(spec.name, "done", why, seconds=dt))
                continue
            code, msg = 1, f"{summary['failed']} (outputs published: keep_failed)"
        dt = time.perf_counter() - t0
        rows.append({"stage": spec.name, "status": "failed", "reason": msg, "seconds": round(dt, 3),
                     **({"warnings": said} if said else {})})
        emit(StageEvent(spec.name, "failed", msg, seconds=dt))
        result.exit_code, result.error = code, f"stage {spec.name}: {msg}"
        break
    _write_run_json(result)
    return result


def _report_warnings(page: Path, said: list[str]) -> None:
    """Add the stage's warnings (as in run.json) to its ``report.html`` as a warning note."""
    from skyrig.io._text import atomic_write
    from skyrig.report.html import add_stage_warnings

    text = page.read_text(encoding="utf-8")
    new = add_stage_warnings(text, said)
    if new != text:
        with atomic_write(page) as fh:
            fh.write(new)


@contextmanager
def _warnings_into(said: list[str]) -> Iterator[None]:
    """Every warning shown while the block runs is also appended to ``said`` as one line of words."""
    import warnings

    with warnings.catch_warnings():  # restores the display afterwards
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
            said.append(" ".join(str(message).split()))
            shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _write_run_json(result: RunResult) -> None:
    from skyrig import __version__

    out = result.project.output
    try:
        out.mkdir(parents=True, exist_ok=True)
        tmp = out / ".run.json.tmp"
        tmp.write_text(json.dumps({"format": "skyrig-run", "version": 1, "software": f"skyrig {__version__}",
                                   "project": str(result.project.path), "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                                   "exit_code": result.exit_code, "error": result.error, "stages": result.stages},
                                  indent=1, default=str) + "\n")
        os.replace(tmp, out / "run.json")
    except OSError as exc:  # the run's own outcome matters more than its log
        logger.warning("could not write %s: %s", out / "run.json", exc)


# ------------------------------------------------------------------------------------------ helpers for stages
def _opt_files(*paths: Path | None) -> list[Path]:
    return [p for p in paths if p is not None]


def _rig_or_cameras(project: Project) -> list[Path]:
    return [project.rig] if project.rig is not None else list(project.cameras)


def _stage_cameras(ctx: StageContext) -> list[Path]:
    """The cameras of a product stage: a self-calibrated camera published by an earlier stage (adjust-uav's
    camera.yaml) before the project's rig / camera files."""
    return [ctx.upstream["cameras"]] if "cameras" in ctx.upstream else _rig_or_cameras(ctx.project)


def _product_check(name: str) -> Callable[[Project, dict[str, Any]], tuple[str, str] | None]:
    def check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
        if not p.images:
            return "inputs.images", f"stage {name} needs inputs.images (image folders)"
        if not _rig_or_cameras(p) and not any(s.name == "adjust-uav" for s in p.stages):
            return "inputs.rig", f"stage {name} needs the cameras: inputs.rig, inputs.cameras or an adjust-uav stage"
        return None
    return check


# ------------------------------------------------------------------------------------------ built-in stages
def _georef_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    return _opt_files(p.trajectory, p.events, p.rig)


def _georef_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    missing = [k for k in ("trajectory", "events", "rig") if getattr(p, k) is None]
    if missing:
        return f"inputs.{missing[0]}", f"stage georef needs inputs {', '.join(missing)}"
    return None


def _georef(ctx: StageContext) -> dict[str, Any]:
    from skyrig.georef.direct import direct_georeference
    from skyrig.georef.eo import WorldFrame
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.rig_file import read_rig

    p, o = ctx.project, ctx.options
    if p.trajectory is None or p.events is None or p.rig is None:  # checked on loading; a registry bug otherwise
        raise StageError("georef", "needs inputs trajectory, events and rig", 2)
    if p.trajectory.suffix.lower() in (".out", ".sbet", ".bin"):
        from skyrig.io.sbet import read_sbet

        traj = read_sbet(p.trajectory, reference=o["sbet_reference"])
    else:
        from skyrig.io.trajectory_csv import read_trajectory_csv

        traj = read_trajectory_csv(p.trajectory)
    frame = WorldFrame.map(p.crs, p.geoid)
    eo = direct_georeference(traj, read_rig(p.rig), read_events_csv(p.events), frame, position=o["position"])
    write_eo_csv(eo, ctx.out / "eo.csv", unit="deg", convention=o["convention"])
    return {"images": len(eo), "heads": len(set(eo.head)) if eo.head is not None else 1, "frame": frame.describe()}


def _match_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    return [*p.images, *_rig_or_cameras(p)]


def _match_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    if not p.images:
        return "inputs.images", "stage match needs inputs.images (image folders)"
    return None


def _match(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.match import match_images
    from skyrig.match.features import FeatureConfig

    p, o = ctx.project, ctx.options
    eo = cameras = None
    th = o["terrain_height"]
    if "eo" in ctx.upstream:
        from skyrig.io.eo_csv import read_eo_csv
        from skyrig.pipeline.inputs import load_cameras

        eo = read_eo_csv(ctx.upstream["eo"])
        cameras = load_cameras([str(c) for c in _rig_or_cameras(p)], "inputs.rig")
        if th is None:
            raise StageError("match", "guided matching with the georeferenced orientations needs "
                             "stages.match.terrain_height (mean terrain height in the output heights, m)", 2)
    fc = FeatureConfig(method=o["method"], max_size=o["max_size"], max_features=o["max_features"])  # type: ignore[arg-type]
    key = _sha(json.dumps({"f": [o["method"], o["max_size"], o["max_features"]], "lsm": o["lsm"]}).encode())[:12]
    cache = ctx.cache() / key  # features and matches kept between runs (MatchDatabase refuses other settings)
    ex = p.executor
    # serial, local processes or a cluster: the same tie points (pipeline.match seeds every pair); not Dask's
    # thread pool, whose threads share the C library's rand and make the matches depend on their order
    scheduler = ex.scheduler or ("sync" if ex.kind == "serial" else "processes")
    done_total: dict[str, tuple[int, int]] = {}

    def progress(stage: str, done: int, total: int) -> None:
        done_total[stage] = (done, total)
        ctx.progress(sum(d for d, _ in done_total.values()), sum(t for _, t in done_total.values()))

    r = match_images(p.images, cache, fc, None, o["pairs"], eo, cameras, th, o["min_overlap"], o["neighbours"],
                     scheduler, ex.workers or 2, o["thin"], False, progress, o["lsm"], o["max_heading_diff"],
                     max_pairs_per_image=o["max_pairs_per_image"])
    for f in ("tie_points.csv", "report.json", "coverage.png"):
        if (cache / f).exists():
            shutil.copy2(cache / f, ctx.out / f)
    rep = r.report
    return {"images": len(r.names), "skipped": len(r.skipped), "pairs": rep.get("pairs_tried"),
            "pairs_overlapping": rep.get("pairs_overlapping"),
            "tie_points": rep.get("n_tracks"), "observations": rep.get("n_observations"), "pair_mode": r.pair_mode}


def _block_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    return _opt_files(p.trajectory, p.events, p.rig, p.eo, *p.cameras, p.control, p.check, *p.measurements, p.ties)


def _matched_before(p: Project, stage: str) -> bool:
    names = [s.name for s in p.stages]
    return "match" in (names[:names.index(stage)] if stage in names else names)


def _block_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    rig_mode = p.trajectory is not None and p.events is not None and p.rig is not None
    if not rig_mode and (p.eo is None or not (p.cameras or p.rig)):
        return "inputs", "stage block needs inputs trajectory + events + rig (rig mode) or eo + cameras (image mode)"
    if p.ties is not None and _matched_before(p, "block"):
        return "inputs.ties", "give the tie points either by a match stage or by inputs.ties, not both"
    if p.ties is None and not p.measurements and not _matched_before(p, "block"):
        return "stages.block", "stage block needs image measurements: a match stage before it, inputs.ties or " \
                               "inputs.measurements"
    if o["datum_points"] is not None and o["datum"] != "free-points":
        return "stages.block.datum_points", "goes with stages.block.datum: free-points"
    if o["fourier_order"] is not None and "actuator-curve" not in o["free"]:
        return "stages.block.fourier_order", "goes with stages.block.free: [actuator-curve]"
    return None


#: How a project names the inputs of the orientation functions (the rest are stage options).
_INPUT_NAMES = {"trajectory": "inputs.trajectory", "events": "inputs.events", "rig": "inputs.rig",
                "eo": "inputs.eo", "camera": "inputs.cameras", "control": "inputs.control", "check": "inputs.check",
                "measurements": "inputs.measurements", "points_crs": "the control file's '# crs:' header",
                "crs": "crs", "geoid": "geoid", "images": "inputs.images", "match": "the match stage / inputs.ties",
                "scale_bars": "inputs.scale_bars"}


def _project_spelling(stage: str) -> Callable[[str], str]:
    """How a project file names what an orientation function calls ``name``: an input or ``stages.<stage>.name``."""
    return lambda name: _INPUT_NAMES.get(name, f"stages.{stage}.{name}")


def _block(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.orientation import make_block

    p, o = ctx.project, ctx.options
    rig_mode = p.trajectory is not None and p.events is not None and p.rig is not None
    mode: dict[str, Any] = ({"trajectory": p.trajectory, "events": p.events, "rig": p.rig} if rig_mode
                            else {"eo": p.eo, "cameras": _rig_or_cameras(p)})
    ties = ctx.upstream.get("ties") or p.ties  # an earlier match stage's, or the project's inputs.ties
    res = make_block(ctx.out / "block.json", [*_opt_files(ties), *p.measurements], **mode, control=p.control,
                     check=p.check, sigma_px=o["sigma_px"], gnss_sigma=o["gnss_sigma"],
                     imu_sigma_deg=o["imu_sigma_deg"], control_sigma=o["control_sigma"], free=o["free"],
                     start_values_only=o["start_values_only"], datum=o["datum"], datum_points=o["datum_points"],
                     fourier_order=o["fourier_order"], crs=p.crs, geoid=p.geoid,
                     snooping_per_round=o["snooping_per_round"],
                     snooping_per_round_share=o["snooping_per_round_share"], spell=_project_spelling("block"))
    return res.summary()


def _adjust(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.orientation import make_adjustment

    o = ctx.options
    res = make_adjustment(ctx.need("block"), ctx.out, preset=o["preset"], gsd=o["gsd"], keep_failed=o["keep_failed"],
                          callback=lambda stage, it, cost: logger.debug("stage adjust: %s iteration %d cost %.6g",
                                                                         stage, it, cost),
                          spell=_project_spelling("adjust"))
    for line in [*res.notices, *res.warnings]:
        logger.warning("stage adjust: %s", line)
    return _failed_or_summary("adjust", res.summary(), res.failures, bool(res.paths))


def _failed_or_summary(stage: str, summary: dict[str, Any], failures: list[str], written: bool) -> dict[str, Any]:
    """A stage's summary, or for a failed adjustment ``{"failed": reason}`` when its outputs were written
    (``keep_failed``: the runner publishes them and still stops with status 1), else a :class:`StageError`."""
    if not failures:
        return summary
    reason = "the adjustment failed: " + "; ".join(failures)
    if written:
        return {**summary, "failed": reason}
    raise StageError(stage, reason + f" (nothing published; stages.{stage}.keep_failed publishes the outputs)", 1)


def _uav_camera(p: Project) -> Path | None:
    return p.cameras[0] if p.cameras else p.rig


def _adjust_uav_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    files = [*p.images, *_opt_files(p.ties)]
    if o["no_gps"]:
        files += _opt_files(p.control, p.check, p.scale_bars, _uav_camera(p), *p.measurements)
    elif p.control or p.check:
        files += _opt_files(p.control, p.check, *p.measurements)
    return files


def _adjust_uav_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    matched = _matched_before(p, "adjust-uav")
    if p.ties is not None and matched:
        return "inputs.ties", "give the tie points either by a match stage or by inputs.ties, not both"
    if p.ties is None and not matched:
        return "stages.adjust-uav", "stage adjust-uav needs tie points: a match stage before it, or inputs.ties"
    if not o["no_gps"]:
        if o["datum"] != "auto":
            return "stages.adjust-uav.datum", "a datum is chosen only without GNSS: set stages.adjust-uav.no_gps: true"
        if p.scale_bars is not None:
            return "inputs.scale_bars", "scale bars are used only without GNSS: set stages.adjust-uav.no_gps: true"
        if len(p.images) != 1:
            return "inputs.images", "stage adjust-uav needs exactly one image folder (images with EXIF GPS)"
        return None
    if len(p.images) > 1:
        return "inputs.images", "stage adjust-uav orients one image folder"
    if not p.images and _uav_camera(p) is None:
        return "inputs.cameras", "stage adjust-uav without images needs the start camera (inputs.cameras)"
    if len(p.cameras) > 1:
        return "inputs.cameras", "stage adjust-uav takes one start camera file"
    return None


def _adjust_uav(ctx: StageContext) -> dict[str, Any]:
    from skyrig.orient.incremental import OrientError
    from skyrig.pipeline.orientation import make_uav_orientation

    p, o = ctx.project, ctx.options
    ties = ctx.upstream.get("ties") or p.ties  # an earlier match stage's, or the project's inputs.ties
    if ties is None:  # checked on loading; a registry bug otherwise
        raise StageError("adjust-uav", "no tie points (a match stage or inputs.ties)", 2)
    kw: dict[str, Any] = {}
    if o["no_gps"]:
        kw = dict(control=p.control, control_sigma=o["control_sigma"], check=p.check, scale_bars=p.scale_bars,
                  measurements=p.measurements, camera=_uav_camera(p), datum=o["datum"])
    elif p.control or p.check:  # ground control / check points join the GNSS-supported block
        kw = dict(control=p.control, control_sigma=o["control_sigma"], check=p.check, measurements=p.measurements)
    try:
        res = make_uav_orientation(p.images[0] if p.images else None, ties, ctx.out, no_gps=o["no_gps"],
                                   gnss_sigma=o["gnss_sigma"], attitude_sigma=o["attitude_sigma"],
                                   altitude=o["altitude"], focal_prior=o["focal_prior"],
                                   free_intrinsics=o.get("free_intrinsics") or (),
                                   rolling_shutter=o.get("rolling_shutter") or "auto",
                                   self_calibration=o["self_calibration"], crs=p.crs,
                                   compare_pycolmap=o["compare_pycolmap"], pycolmap_size=o["pycolmap_size"],
                                   pycolmap_mapper=o["pycolmap_mapper"], pycolmap_input=o["pycolmap_input"],
                                   spell=_project_spelling("adjust-uav"), **kw)
    except OrientError as exc:  # the set could not be oriented: a failed run, not bad input
        raise StageError("adjust-uav", f"the orientation failed: {exc}", 1) from None
    # the outputs are in ctx.out either way: published with FAILED.txt when keep_failed, else dropped
    return _failed_or_summary("adjust-uav", res.summary(), res.failures, o["keep_failed"])


def _dsm_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    return [*p.images, *_rig_or_cameras(p)]


def _stage_eo_cameras(ctx: StageContext) -> tuple[Any, dict[str, Any], list[Path]]:
    """The latest orientations (eo.csv of an earlier stage) and the stage's cameras, with the files they came from."""
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.pipeline.inputs import load_cameras

    cams = _stage_cameras(ctx)
    eo_path = ctx.need("eo")
    return read_eo_csv(eo_path), load_cameras(cams, f"inputs of stage {ctx.spec.name}"), [eo_path, *cams]


def _executor_kw(ex: ExecutorSpec) -> dict[str, Any]:
    """``executor`` / ``workers`` / ``scheduler`` of the product functions from the project's executor."""
    if ex.scheduler:
        return {"executor": "scheduler", "workers": ex.workers, "scheduler": ex.scheduler}
    return {"executor": ex.kind, "workers": ex.workers, "scheduler": None}


def _spelling(stage: str) -> Callable[[str], str]:
    """How a project file names a stage option (``stages.dsm.resolution``)."""
    return lambda name: f"stages.{stage}.{name}"


def _dsm(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.products import make_dsm

    p, o = ctx.project, ctx.options
    eo, cameras, files = _stage_eo_cameras(ctx)
    points = None
    if o["height_range"] is None:
        if "points" not in ctx.upstream:
            raise StageError("dsm", "no sparse points from an earlier stage: give stages.dsm.height_range [MIN, MAX]", 2)
        points = ctx.upstream["points"]
    res = make_dsm(eo, cameras, p.images, ctx.out, crs=p.crs, geoid=p.geoid, height_range=o["height_range"],
                   points=points, heads=o["heads"], area=o["area"], resolution=o["resolution"], mode=o["mode"],
                   lr_check=o["lr_check"], lr_band_cols=o["lr_band_cols"], pairs_per_image=o["pairs_per_image"], min_support=o["min_support"], fill=o["fill"],
                   cloud=o["cloud"], min_depth=o["min_depth"], tile_cells=o["tile_cells"], image_scale=o["image_scale"],
                   tile_memory_mb=o["tile_memory_mb"],
                   orientation_sigma_px=o["orientation_sigma_px"],
                   **_executor_kw(p.executor), inputs=files, progress=ctx.progress,
                   echo=lambda line: logger.info("stage dsm: %s", line), spell=_spelling("dsm"))
    s = res.summary
    return {"pairs": len(s["pairs"]), "cells_valid": s["cells_valid"], "cells": s["cells"],
            "cloud_points": s["cloud_points"]}


register_stage(Stage(
    "georef", "Direct georeferencing: trajectory + events + rig -> eo.csv in the project CRS.", _georef,
    options={"convention": Option("opk", "choice", "angle convention of eo.csv", ("opk", "pok", "ypr")),
             "position": Option("cubic", "choice", "position interpolation", ("cubic", "linear")),
             "sbet_reference": Option("imu", "choice", "point an SBET's positions refer to", ("imu", "antenna"))},
    provides={"eo": "eo.csv"}, inputs=_georef_inputs, check=_georef_check))
register_stage(Stage(
    "match", "Tie points (SIFT, guided by the georeferenced orientations when an earlier stage gives them).", _match,
    options={"terrain_height": Option(None, "float", "mean terrain height (m, output heights) for guided pairs",
                                      nullable=True),
             "pairs": Option("auto", "choice", "pair selection", ("auto", "guided", "gps", "exhaustive")),
             "method": Option("pycolmap", "choice", "SIFT implementation", ("pycolmap", "opencv")),
             "max_size": Option(1600, "int", "detect on images downscaled to this (px)", positive=True),
             "max_features": Option(8000, "int", "features per image", positive=True),
             "min_overlap": Option(0.1, "float", "guided pairs: footprint overlap", positive=True),
             "max_pairs_per_image": Option(12, "int", "guided pairs: per-image budget (strongest overlaps, "
                                           "connected, head and strip links kept); 0 or null = all", nullable=True),
             "neighbours": Option(8, "int", "gps pairs: nearest images", positive=True),
             "max_heading_diff": Option(None, "float", "gps pairs: heading filter (deg)", nullable=True),
             "thin": Option(0, "int", "tracks kept per 8x8 image cell (0 = all)"),
             "lsm": Option(False, "bool", "refine tie points by least-squares matching")},
    uses=("eo",), provides={"ties": "tie_points.csv"}, inputs=_match_inputs, check=_match_check))
register_stage(Stage(
    "block", "Block file: stations from trajectory/events/rig (or EO), tie points, control measurements, control.",
    _block,
    options={"sigma_px": Option(0.5, "float", "image measurement sigma (px)", positive=True),
             "gnss_sigma": Option([0.05, 0.05, 0.08], "floats", "GNSS sigma E, N, U (m)", n=3, positive=True),
             "imu_sigma_deg": Option([0.005, 0.005, 0.01], "floats", "IMU sigma roll, pitch, yaw (deg)", n=3,
                                     positive=True),
             "control_sigma": Option([0.02, 0.02, 0.02], "floats", "control point sigma X, Y, Z (m)", n=3,
                                     positive=True),
             "free": Option([], "strs", "system-calibration groups to estimate",
                            ("boresight", "lever-arm", "datum-shift", "strip-shift", "intrinsics", "actuator",
                             "actuator-curve")),
             "fourier_order": Option(None, "int", "order of the Fourier boresight curve with free: "
                                     "[actuator-curve] (default 2)", nullable=True, positive=True),
             "start_values_only": Option(False, "bool", "trajectory / EO as starting values only, not GNSS/IMU "
                                         "observations (datum from control or datum: free)"),
             "datum": Option("auto", "choice", "auto: control and/or GNSS; free: inner constraints on the stations; "
                             "free-points: on object points; none", ("auto", "free", "free-points", "none")),
             "datum_points": Option(None, "strs", "with datum: free-points, the points defining it (default all)",
                                    nullable=True),
             "snooping_per_round": Option(10, "int", "image observations data snooping rejects per round at most "
                                          "(non-adjacent; 1: one at a time)", positive=True),
             "snooping_per_round_share": Option(0.0, "float", "... or this share of the tested observations when "
                                                "that is more (e.g. 0.001: the rounds do not grow with the block; "
                                                "0: snooping_per_round alone)")},
    uses=("ties",), provides={"block": "block.json"}, inputs=_block_inputs, check=_block_check))
register_stage(Stage(
    "adjust", "Bundle adjustment / integrated sensor orientation: eo.csv, points.csv, report in the project CRS.",
    _adjust,
    options={"preset": Option(None, "str", "paper-004 variant (skyrig adjust --preset)", nullable=True),
             "gsd": Option(None, "float", "GSD (m) for RMS in GSD units", nullable=True, positive=True),
             "keep_failed": Option(False, "bool", "publish the outputs of a failed adjustment")},
    requires=("block",), provides={"eo": "eo.csv", "points": "points.csv", "report": "report.html"}))
register_stage(Stage(
    "adjust-uav", "GNSS-supported adjustment of UAV images (EXIF GPS, DJI gimbal) with self-calibration; with "
    "no_gps the orientation of a set without GNSS (terrestrial, close range) from a two-view start.", _adjust_uav,
    options={"gnss_sigma": Option([2.0, 2.0, 4.0], "floats", "GNSS sigma E, N, U (m)", n=3, positive=True),
             "attitude_sigma": Option(5.0, "float", "gimbal attitude sigma (deg)", positive=True),
             "altitude": Option("egm96", "choice", "what EXIF GPSAltitude is", ("egm96", "ellipsoidal")),
             "focal_prior": Option(None, "float", "relative sigma of the focal length prior (default: the sigma of its "
                                   "source: 1 % vendor XMP, 3 % EXIF focal + sensor database, 10 % 35-mm value)",
                                   nullable=True, positive=True),
             "free_intrinsics": Option([], "strs", "intrinsics left free even when the block cannot determine them "
                                       "(default: held at the prior with a warning)"),
             "self_calibration": Option(True, "bool", "self-calibrate the camera"),
             "rolling_shutter": Option("auto", "choice", "model the rolling shutter (auto: for cameras known to have "
                                       "one, e.g. DJI FC300S / FC330, phones)", ("auto", "on", "off")),
             "keep_failed": Option(False, "bool", "publish the outputs of a failed adjustment"),
             "no_gps": Option(False, "bool", "orient without GNSS (two-view start, resection, bundle adjustment): "
                              "start camera from inputs.cameras or EXIF, datum from inputs.control / scale_bars"),
             "datum": Option("auto", "choice", "with no_gps: what fixes the datum (auto: control, else scale bars, "
                             "else a similarity onto EXIF GPS, else a free network)",
                             ("auto", "control", "scale-bar", "gps-similarity", "free")),
             "control_sigma": Option([0.01, 0.01, 0.01], "floats", "control point sigma X, Y, Z (m; metre-class "
                                     "targets: e.g. [1.5, 1.5, 10])", n=3),
             "compare_pycolmap": Option(False, "bool", "also run pycolmap's own reconstruction and compare centres"),
             "pycolmap_size": Option(1600, "int", "pycolmap comparison: SIFT on images downscaled to this (px)",
                                     positive=True),
             "pycolmap_mapper": Option("incremental", "choice", "pycolmap comparison: mapper",
                                       ("incremental", "global")),
             "pycolmap_input": Option(None, "choice", "pycolmap comparison on images (its own matching) or tracks "
                                      "(skyrig's tie points); null: images when there are image files, else tracks",
                                      ("images", "tracks"), nullable=True)},
    uses=("ties",), provides={"eo": "eo.csv", "points": "points.csv", "cameras": "camera.yaml"},
    inputs=_adjust_uav_inputs,
    check=_adjust_uav_check))
register_stage(Stage(
    "dsm", "Dense matching: DSM (COG), dense cloud (LAZ), hillshade from the latest orientations.", _dsm,
    options={"heads": Option([], "strs", "rig heads / image-name parts to use (e.g. [nadir]); [] = all"),
             "height_range": Option(None, "floats", "expected surface heights [MIN, MAX] (m); default from the "
                                    "adjusted points", n=2, nullable=True),
             "area": Option(None, "floats", "[XMIN, YMIN, XMAX, YMAX] in the project CRS", n=4, nullable=True),
             "resolution": Option(None, "float", "cell size (m); default 1 GSD", nullable=True, positive=True),
             "mode": Option("sgbm", "choice", "OpenCV SGM mode", ("sgbm", "hh", "3way", "hh4")),
             "lr_check": Option("banded", "choice", "left-right check: a second, mirrored matching on the row bands "
                                "with depth edges (banded), on every row (full), or OpenCV's own on the same costs "
                                "(opencv: half the matching time, rounder building edges)",
                                ("banded", "full", "opencv")),
             "lr_band_cols": Option(None, "int", "banded check: the second matching only on the columns within this "
                                    "many pixels of a depth edge (>= 0; 0: the bands' whole rows; null: 8)",
                                    nullable=True),
             "pairs_per_image": Option(6, "int", "stereo pairs per image", positive=True),
             "min_support": Option(2, "int", "pairs that must agree on a cell", positive=True),
             "tile_cells": Option(2048, "int", "ground tile side in cells", positive=True),
             "tile_memory_mb": Option(1024.0, "float", "memory budget of a tile's work (MiB): tiles up to tile_cells "
                                      "whose predicted points and images fit; null = tiles of tile_cells",
                                      nullable=True, positive=True),
             "min_depth": Option(None, "float", "nearest searched depth (m)", nullable=True, positive=True),
             "image_scale": Option("auto", "choice", "scale of the images dense matching sees, as ODM's quality: "
                                   "ultra 1, high 0.5, medium 0.25, low 0.125, lowest 0.0625; auto: from resolution, "
                                   "without it images of at most 2048 px",
                                   ("auto", "ultra", "high", "medium", "low", "lowest")),
             "orientation_sigma_px": Option(None, "float", "orientations' relative error as a disparity (full-"
                                            "resolution px) in the fusion's tolerance", nullable=True, positive=True),
             "fill": Option(False, "bool", "interpolate small holes (flagged)"),
             "cloud": Option(True, "bool", "write the dense point cloud")},
    requires=("eo",), uses=("points", "cameras"), provides={"dsm": "dsm.tif"}, inputs=_dsm_inputs,
    check=_product_check("dsm")))


def _ortho(ctx: StageContext) -> dict[str, Any]:
    return _ortho_on(ctx, "dsm")


def _ortho_dtm(ctx: StageContext) -> dict[str, Any]:
    return _ortho_on(ctx, "dtm")


def _ortho_on(ctx: StageContext, surface: str) -> dict[str, Any]:
    """The ortho stage (a true orthomosaic on the dsm stage's DSM) or the ortho-dtm stage (a classic one on the dtm
    stage's DTM)."""
    from skyrig.pipeline.products import make_ortho

    p, o = ctx.project, ctx.options
    eo, cameras, files = _stage_eo_cameras(ctx)
    res = make_ortho(eo, cameras, p.images, ctx.need(surface), ctx.out, heads=o["heads"],
                     head_mosaics=o["head_mosaics"], area=o["area"], resolution=o["resolution"],
                     max_off_nadir=o["max_off_nadir"], feather=o["feather"], balance=o["balance"],
                     square=o.get("square", False), tile_cells=o["tile_cells"], **_executor_kw(p.executor),
                     inputs=files, progress=ctx.progress, spell=_spelling(ctx.spec.name), surface=surface)
    s = res.summary
    return {"cells_valid": s["cells_valid"], "cells": s["cells"], "images_used": len(s["images_used"]),
            "seamlines": s["seamlines"]}


def _footprints_path(p: Project, o: dict[str, Any]) -> Path | None:
    """The facades stage's ``footprints`` (relative to the project file's folder)."""
    return None if o["footprints"] is None else (p.path.parent / o["footprints"]).resolve()


def _facades_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    fp = _footprints_path(p, o)
    return [*_dsm_inputs(p, o), *([fp] if fp is not None else [])]


def _facades(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.products import make_facades

    p, o = ctx.project, ctx.options
    eo, cameras, files = _stage_eo_cameras(ctx)
    res = make_facades(eo, cameras, p.images, ctx.need("dsm"), ctx.out, heads=o["heads"],
                       footprints=_footprints_path(p, o), ortho=ctx.upstream.get("ortho"), texel=o["texel"],
                       max_images=o["max_images"], refine=o["refine"], inputs=files, progress=ctx.progress,
                       spell=_spelling("facades"), footprint_layer=o["footprint_layer"],
                       footprint_eave=o["footprint_eave"], footprint_ridge=o["footprint_ridge"],
                       footprint_heights=o["footprint_heights"], footprint_mode=o["footprint_mode"],
                       refine_footprints=o["refine_footprints"])
    s = res.summary
    return {"buildings": s["buildings"], "facades": s["facades"], "facades_seen": s["facades_seen"]}


_ORTHO_OPTIONS = {
    "heads": Option([], "strs", "rig heads / image-name parts of the main mosaic (e.g. [nadir]); [] = all"),
    "head_mosaics": Option([], "strs", "also one mosaic per head (e.g. [forward, backward, left, right])"),
    "area": Option(None, "floats", "[XMIN, YMIN, XMAX, YMAX] in the DSM's CRS", n=4, nullable=True),
    "resolution": Option(None, "float", "cell size (m); default 1 GSD", nullable=True, positive=True),
    "max_off_nadir": Option(60.0, "float", "steepest view angle a cell takes (deg)", positive=True),
    "feather": Option(None, "float", "blend width across seamlines (m)", nullable=True, positive=True),
    "balance": Option(True, "bool", "radiometric balance between images"),
    "square": Option(True, "bool", "square the buildings' edges in the surface (no leaning roofs)"),
    "tile_cells": Option(2048, "int", "tile side in cells", positive=True)}
register_stage(Stage(
    "ortho", "True orthomosaic (COG, source layer, seamlines) of the oriented images on the DSM.", _ortho,
    options=_ORTHO_OPTIONS,
    requires=("eo", "dsm"), uses=("cameras",), provides={"ortho": "ortho.tif"}, inputs=_dsm_inputs,
    check=_product_check("ortho")))
register_stage(Stage(
    "facades", "Buildings, façade textures and a textured 3D model (GLB, OBJ, viewer) from the DSM and the images.",
    _facades,
    options={"heads": Option([], "strs", "rig heads / image-name parts to texture from; [] = all"),
             "footprints": Option(None, "file", "GeoPackage of building footprints, relative to the project "
                                  "file (default: from the DSM)",
                                  nullable=True),
             "footprint_layer": Option(None, "str", "layer of footprints (default: 'buildings', else the only "
                                       "polygon layer)", nullable=True),
             "footprint_eave": Option(None, "str", "attribute of footprints: eave height (m) where the DSM has none",
                                      nullable=True),
             "footprint_ridge": Option(None, "str", "attribute of footprints: ridge height (m)", nullable=True),
             "footprint_heights": Option("above-ground", "choice", "reference of the footprint heights",
                                         choices=("above-ground", "absolute")),
             "footprint_mode": Option("replace", "choice", "replace: the footprints are the buildings; complete: "
                                      "the DSM's buildings completed by the footprints they miss",
                                      choices=("replace", "complete")),
             "refine_footprints": Option(False, "bool", "move the footprints' walls onto their feet as the "
                                         "obliques show them"),
             "texel": Option(None, "float", "façade texel size (m)", nullable=True, positive=True),
             "max_images": Option(3, "int", "images blended into one façade at most", positive=True),
             "refine": Option(True, "bool", "move DSM-extracted walls onto the roof outline seen in the images")},
    requires=("eo", "dsm"), uses=("ortho", "cameras"), provides={"model": "model.glb"}, inputs=_facades_inputs,
    check=_product_check("facades")))


def _dtm(ctx: StageContext) -> dict[str, Any]:
    """Classify the laser cloud of the lidar stage, else the dsm stage's dense cloud (cloth simulation filter +
    ASPRS rule) and grid the DTM (on the DSM's grid when there is one)."""
    from skyrig.pipeline.terrain import classify_cloud_file, dtm_folder
    from skyrig.terrain.classify import GroundFilter

    o = ctx.options
    dsm: Path | None
    if "laser" in ctx.upstream:
        cloud, dsm = ctx.need("laser"), None
    else:
        dsm = ctx.need("dsm")
        cloud = dsm.parent / "cloud.laz"
    if not cloud.is_file():
        raise StageError("dtm", f"the dsm stage wrote no dense cloud ({cloud}): set stages.dsm.cloud: true", 2)
    c = classify_cloud_file(cloud, ctx.out / "classified.laz",
                            ground=GroundFilter(cloth_resolution_m=o["cloth_resolution"], rigidness=o["rigidness"]),
                            tile_m=o["tile"], buffer_m=o["buffer"], **_executor_kw(ctx.project.executor),
                            progress=ctx.progress)
    s = dtm_folder(ctx.out / "classified.laz", ctx.out, dsm=dsm, cell_m=o["resolution"], max_gap_m=o["max_gap"],
                   published=False, tile_m=o["tile"], buffer_m=o["buffer"], **_executor_kw(ctx.project.executor))
    return {"points": c["points"], "classes": c["classes"], "cells_by_source": s["cells_by_source"]}


register_stage(Stage(
    "dtm", "Terrain: ASPRS classes of the dense cloud (classified.laz), DTM with mask, nDSM, hillshade.", _dtm,
    options={"cloth_resolution": Option(1.0, "float", "cloth simulation filter: cloth spacing (m)", positive=True),
             "rigidness": Option(2, "int", "cloth rigidness: 1 steep, 2 relief, 3 flat", positive=True),
             "resolution": Option(None, "float", "DTM cell size (m); default the DSM's (1 m on a laser cloud)",
                                  nullable=True,
                                  positive=True),
             "max_gap": Option(20.0, "float", "open gaps farther than this from ground stay without data (m)",
                               positive=True),
             "tile": Option(500.0, "float", "a wider cloud is classified and gridded in tiles of this side (m)",
                            positive=True),
             "buffer": Option(50.0, "float", "buffer around each tile (m); holds the largest building",
                              positive=True)},
    requires=("laser|dsm",), provides={"dtm": "dtm.tif", "classified": "classified.laz"}))
register_stage(Stage(
    "ortho-dtm", "Classic orthomosaic of the oriented images on the DTM (next to the true ortho: buildings lean).",
    _ortho_dtm, options={k: v for k, v in _ORTHO_OPTIONS.items() if k != "square"},
    requires=("eo", "dtm"), uses=("cameras",), provides={"ortho_dtm": "ortho.tif"}, inputs=_dsm_inputs,
    check=_product_check("ortho-dtm")))



def _live_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    dem = None if o["dem"] is None else p.root / Path(o["dem"]).expanduser()
    return _opt_files(p.rig, p.trajectory, p.events, p.images[0] if p.images else None, dem)


def _live_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    from skyrig.pipeline.live_project import live_problem

    return live_problem(p, o)


def _live(ctx: StageContext) -> dict[str, Any]:
    from skyrig.pipeline.live_project import live_stage

    return live_stage(ctx.out, ctx.project, ctx.options)


register_stage(Stage(
    "live", "Near-real-time chain (skyrig live) over the flight: DG, ortho and DSM XYZ tiles, online boresight; "
            "with skyrig run --live while the flight is recorded, else over the recorded flight.", _live,
    options={"height": Option(None, "float", "reference plane height (m, ellipsoidal; default: the DEM's median, "
                                             "else the match stage's terrain_height)", nullable=True),
             "height_sigma": Option(5.0, "float", "standard deviation of the reference surface (m)", positive=True),
             "dem": Option(None, "file", "reference DEM (GeoTIFF in the output CRS, ellipsoidal heights)",
                           nullable=True),
             "cell": Option(None, "float", "ortho cell (m) choosing the finest tile zoom; default each image's GSD",
                            nullable=True, positive=True),
             "window": Option(8, "int", "exposures per online boresight adjustment (0: none)"),
             "dsm": Option(True, "bool", "DSM tiles of consecutive stereo-head images"),
             "stereo_head": Option(None, "str", "head of the DSM pairs (default: the one closest to nadir)",
                                   nullable=True),
             "zoom_levels": Option(4, "int", "tile zoom levels below the finest"),
             "image_timeout": Option(20.0, "float", "seconds an image may take to be written", positive=True),
             "trajectory_timeout": Option(20.0, "float", "seconds an exposure past the trajectory's end waits",
                                          positive=True),
             "idle_stop": Option(None, "float", "--live: stop after this many seconds without new input (default: "
                                                "when end_file appears)", nullable=True, positive=True),
             "end_file": Option("flight.end", "str", "--live: the file (relative to the project folder) the "
                                                      "recording system writes when the flight is over")},
    provides={"live_tiles": "tiles", "live_summary": "summary.json"}, inputs=_live_inputs, check=_live_check))


# ------------------------------------------------------------------------------------------ laser
def _lidar_inputs(p: Project, o: dict[str, Any]) -> list[Path]:
    return [*p.laser, *_opt_files(p.trajectory, p.rig), *([p.root / o["reference"]] if o["reference"] else [])]


def _lidar_check(p: Project, o: dict[str, Any]) -> tuple[str, str] | None:
    if not p.laser:
        return "inputs.laser", "the lidar stage needs laser data: a raw scan CSV with strips or LAS/LAZ files"
    if any(q.suffix.lower() == ".csv" for q in p.laser):
        if p.trajectory is None:
            return "inputs.trajectory", "a raw scan needs the trajectory"
        if p.rig is None:
            return "inputs.rig", "a raw scan needs a rig file with a 'scanners' record (the scanner's mount)"
    return None


def _lidar(ctx: StageContext) -> dict[str, Any]:
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.pipeline.lidar import laser_folder

    p, o = ctx.project, ctx.options
    deg = 3.141592653589793 / 180.0
    opts = {"scanner": o["scanner"], "reference": str(p.root / o["reference"]) if o["reference"] else None,
            "name": o["scanner"] or "lidar", "offsets": o["offsets"], "cell_lines": o["line_cell"],
            "model": {"range_sigma_m": o["range_sigma"], "scan_angle_sigma_rad": o["angle_sigma_deg"] * deg,
                      "strip_position_sigma_m": tuple(o["position_sigma"]),
                      "strip_attitude_sigma_rad": tuple(v * deg for v in o["attitude_sigma_deg"])},
            "patches": {"cell_m": o["cell"]}}
    if o["estimate"] is not None:
        opts["estimate"] = tuple(o["estimate"])
    s = laser_folder(p.laser, ctx.out, WorldFrame.map(p.crs, p.geoid), trajectory=p.trajectory, rig=p.rig, opts=opts,
                     progress=ctx.progress)
    return {k: s[k] for k in ("mode", "points", "discrepancies_before", "discrepancies_after", "crs",
                              "vertical_reference") if k in s}


register_stage(Stage(
    "lidar", "Laser strips: strip adjustment of a raw scan (calibration + per-strip trajectory corrections) or "
    "per-line offsets of LAS/LAZ; the adjusted cloud (laser.laz) and strip discrepancies (strips.json).", _lidar,
    options={"scanner": Option(None, "str", "scanner record of the rig file (default: its only one)", nullable=True),
             "reference": Option(None, "file", "control: a reference cloud (.las/.laz with a CRS) on the same surfaces",
                                 nullable=True),
             "range_sigma": Option(0.02, "float", "range noise (m)", positive=True),
             "angle_sigma_deg": Option(0.0, "float", "deflection-angle noise (deg)"),
             "position_sigma": Option([0.05, 0.05, 0.08], "floats", "trajectory position accuracy per strip E,N,U (m)",
                                      n=3, positive=True),
             "attitude_sigma_deg": Option([0.03, 0.03, 0.08], "floats",
                                          "trajectory attitude accuracy per strip about E,N,U (deg)", n=3, positive=True),
             "estimate": Option(None, "strs", "calibration unknowns (default all: boresight, lever arm, range offset "
                                "and scale)", nullable=True, choices=("boresight_x", "boresight_y", "boresight_z",
                                                                      "lever_x", "lever_y", "lever_z", "range_offset",
                                                                      "range_scale")),
             "cell": Option(1.0, "float", "planar patch size of the strip adjustment (m)", positive=True),
             "offsets": Option("vertical", "choice", "LAS/LAZ input: per-line offsets vertical or 3d",
                               choices=("vertical", "3d")),
             "line_cell": Option(4.0, "float", "LAS/LAZ input: patch column size (m)", positive=True)},
    provides={"laser": "laser.laz", "strips": "strips.json"}, inputs=_lidar_inputs, check=_lidar_check))

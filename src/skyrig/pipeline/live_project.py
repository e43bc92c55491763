"""The live project mode (issue 35): a project's flight processed as it is recorded, ``skyrig run PROJECT --live``.

A project (``project.yaml``, :mod:`skyrig.pipeline.project`) names where the flight is recorded: ``inputs.rig``
(there from the start), ``inputs.trajectory``, ``inputs.events`` and the first folder of ``inputs.images`` (written
during the flight; in live mode they need not exist when the run starts).  The stage ``live`` (options
``stages.live``, or all defaults when the project does not list it) runs :class:`skyrig.pipeline.live.LiveRun` over
them:

* ``--live``: while the flight is recorded, into the working folder ``OUTPUT/.live.running/`` (served by the live
  page); when the flight is over (the file ``stages.live.end_file`` appears, default ``flight.end`` in the project
  folder, or ``idle_stop`` seconds pass without new input, or Ctrl-C) the products are published as the stage
  folder ``OUTPUT/live/`` in one step (:func:`skyrig.io.stage.stage_folder`: ``manifest.json`` last, with the
  fingerprint of the inputs as they are at the end), and ``OUTPUT/run.json`` says so;
(the run itself: :func:`skyrig.pipeline.live_run.run_live_project`, which uses the runner's fingerprints; this
module is the stage's body, which the runner imports)
* then (``--then-batch``) the project's stages run as ``skyrig run`` runs them (:func:`skyrig.pipeline.run.run_project`);
  a ``live`` stage in the list is then up to date (same inputs, same options) and skipped;
* without ``--live``, a listed ``live`` stage processes the recorded flight through the same chain (a quick look:
  tiles, online boresight), every exposure being there already.

The products (:mod:`skyrig.pipeline.live`): ``tiles/ortho`` and ``tiles/dsm`` (XYZ PNG tiles, Web Mercator),
``latency.jsonl``, ``boresight.jsonl``, ``status.json``, ``summary.json`` and ``_inputs/`` (the trajectory and
events as last read).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from skyrig.errors import SkyrigError
from skyrig.pipeline.live import FlightPaths, LiveConfig, LiveRun
from skyrig.pipeline.spec import Project

__all__ = ["LIVE_STAGE", "WORK_FOLDER", "flight_paths", "live_config", "live_problem", "live_stage",
           "stage_summary"]

LIVE_STAGE = "live"
#: the working folder of a live run in the project's output folder (published as OUTPUT/live at the end)
WORK_FOLDER = ".live.running"


def flight_paths(project: Project, options: dict[str, Any]) -> FlightPaths:
    """Where the project's flight is recorded (its first image folder)."""
    if project.rig is None or project.trajectory is None or project.events is None or not project.images:
        raise SkyrigError("the live stage needs inputs.rig, inputs.trajectory, inputs.events and inputs.images")
    end = Path(options["end_file"]).expanduser()
    return FlightPaths(project.rig, project.trajectory, project.events, project.images[0],
                       end if end.is_absolute() else project.root / end)


def live_problem(project: Project, options: dict[str, Any]) -> tuple[str, str] | None:
    """What keeps the project from a live run: ``(key path, problem)`` or None (the stage's load-time check)."""
    missing = [k for k in ("rig", "trajectory", "events", "images") if not getattr(project, k)]
    if missing:
        return f"inputs.{missing[0]}", f"stage live needs inputs {', '.join(missing)}"
    if project.crs is None:
        return "crs", "stage live needs an output CRS (projected, metres)"
    if options["height"] is None and options["dem"] is None and _match_height(project) is None:
        return ("stages.live.height", "stage live needs the reference surface: stages.live.height (ellipsoidal "
                "height, m) or stages.live.dem (a DEM in the output CRS)")
    return None


def _match_height(project: Project) -> float | None:
    """The match stage's terrain height when it is an ellipsoidal height (no geoid in the project)."""
    if project.geoid is not None:
        return None
    try:
        h = project.stage("match").options.get("terrain_height")
    except KeyError:
        return None
    return None if h is None else float(h)


def live_config(project: Project, options: dict[str, Any]) -> LiveConfig:
    """The :class:`LiveConfig` of the stage's options: the reference height from ``height``, else the DEM's median,
    else the match stage's terrain height."""
    problem = live_problem(project, options)
    if problem is not None:
        raise project.error(problem[1], problem[0])
    dem = None if options["dem"] is None else str(project.root / Path(options["dem"]).expanduser())
    height = options["height"]
    if height is None and dem is not None:
        import numpy as np

        from skyrig.io.dem import read_dem

        height = float(np.nanmedian(read_dem(dem).heights))
    if height is None:
        height = _match_height(project)
    assert project.crs is not None and height is not None
    return LiveConfig(surface_height_m=float(height), surface_sigma_m=options["height_sigma"], dem_path=dem,
                      crs=project.crs, cell_m=options["cell"], dsm=options["dsm"], window=options["window"],
                      stereo_head=options["stereo_head"], zoom_levels=options["zoom_levels"],
                      image_timeout_s=options["image_timeout"], trajectory_timeout_s=options["trajectory_timeout"],
                      idle_stop_s=options["idle_stop"])


def stage_summary(summary: dict[str, Any]) -> dict[str, Any]:
    """The part of a live run's summary that goes into run.json."""
    keep = ("exposures_done", "exposures_skipped", "exposure_interval_s", "ortho_latency_s", "dsm_latency_s",
            "process_cpu_s_per_exposure", "boresight_windows", "boresight_deg", "reported")
    return {k: summary.get(k) for k in keep}


def live_stage(out: Path, project: Project, options: dict[str, Any]) -> dict[str, Any]:
    """The ``live`` stage of a batch run: the recorded flight through the live chain into ``out``."""
    run = LiveRun(flight_paths(project, options), out, live_config(project, options))
    return stage_summary(run.run(complete=True))

"""``skyrig run PROJECT --live``: the live run of a project (:mod:`skyrig.pipeline.live_project`) until the flight
is over, then its products published as the ``live`` stage folder with the runner's fingerprint
(:mod:`skyrig.pipeline.run`).  Apart from :mod:`~skyrig.pipeline.live_project` because the runner imports that one
(the stage's body) and this one imports the runner."""

from __future__ import annotations

import os
import shutil
import threading
import time
from pathlib import Path
from typing import Any, Callable

from skyrig.pipeline.live import LiveRun
from skyrig.pipeline.live_project import LIVE_STAGE, WORK_FOLDER, flight_paths, live_config, stage_summary
from skyrig.pipeline.run import STAGES, RunResult, _write_run_json, stage_fingerprint
from skyrig.pipeline.spec import Project, StageSpec

__all__ = ["live_spec", "run_live_project"]


def live_spec(project: Project) -> StageSpec:
    """The project's ``live`` stage as listed, or the stage with its default options when it lists none."""
    try:
        return project.stage(LIVE_STAGE)
    except KeyError:
        return StageSpec(LIVE_STAGE, {k: o.default for k, o in STAGES[LIVE_STAGE].options.items()})


def run_live_project(project: Project, *, say: Callable[[str], None] | None = None,
                     stop: threading.Event | None = None, max_wall_s: float | None = None,
                     on_start: Callable[[LiveRun], None] | None = None) -> tuple[dict[str, Any], Path]:
    """The live run of ``project`` (loaded with ``live=True``) until the flight is over, then its products
    published as ``OUTPUT/live`` (manifest last) and ``OUTPUT/run.json``; the run's summary and the folder.

    ``on_start(run)`` is called once the run is set up, before the first poll (e.g. to serve ``run.out``, or start
    a replay)."""
    from skyrig.io.stage import stage_folder

    spec = live_spec(project)
    cfg = live_config(project, spec.options)
    work = project.output / WORK_FOLDER
    shutil.rmtree(work, ignore_errors=True)
    t0 = time.time()
    run = LiveRun(flight_paths(project, spec.options), work, cfg, say)
    if on_start is not None:
        on_start(run)
    try:
        summary = run.run(stop, max_wall_s)
    except KeyboardInterrupt:
        summary = run.finish()
    # published as the inputs are now (the flight complete): a later ``skyrig run`` finds the stage up to date
    inputs, options, _ = stage_fingerprint(project, STAGES[LIVE_STAGE], spec, {})
    folder = project.output / LIVE_STAGE
    with stage_folder(folder, stage=LIVE_STAGE, inputs=inputs, options=options, started=t0) as tmp:
        for entry in sorted(work.iterdir()):
            os.replace(entry, tmp / entry.name)
    shutil.rmtree(work, ignore_errors=True)
    row = {"stage": LIVE_STAGE, "status": "done", "reason": "live", "seconds": round(time.time() - t0, 3),
           "summary": stage_summary(summary)}
    _write_run_json(RunResult(project, [row]))
    return summary, folder

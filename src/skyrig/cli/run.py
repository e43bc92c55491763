"""``skyrig init FOLDER`` (a commented project.yaml from what the folder holds) and ``skyrig run [PROJECT]`` (its
stages in order, resumable; :mod:`skyrig.pipeline.run`)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

__all__ = ["init_command", "run_command"]


@click.command("init")
@click.argument("folder", type=click.Path(exists=True, file_okay=False), default=".")
@click.option("--crs", default=None, help="Output CRS (default: from the trajectory / EO header, the control points "
                                          "or the images' EXIF GPS).")
@click.option("--geoid", default=None, help="Geoid grid (path or PROJ name) for orthometric output heights.")
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False),
              help="Project file to write (default FOLDER/project.yaml).")
@click.option("--force", is_flag=True, help="Overwrite an existing project file.")
def init_command(folder: str, crs: str | None, geoid: str | None, output: str | None, force: bool) -> None:
    """Write a commented project.yaml for the flight in FOLDER (images, trajectory, events, rig, control found by reading them)."""
    from skyrig.io._text import atomic_write
    from skyrig.pipeline.project import detect_inputs, parse_project, project_template

    out = Path(output) if output else Path(folder) / "project.yaml"
    if out.exists() and not force:
        raise click.UsageError(f"{out} exists (--force overwrites it)")
    det = detect_inputs(folder)
    text = project_template(det, crs, geoid, base=out.absolute().parent)
    # what is written must read back (a bug otherwise): checked before anything is written, so that a refused
    # project file is never left behind and --force never replaces a good one with a bad one
    proj = parse_project(text, out.absolute())
    with atomic_write(out) as fh:
        fh.write(text)
    found = [f"{k} {getattr(det, k).name}" for k in ("trajectory", "events", "rig", "eo", "control", "check")
             if getattr(det, k) is not None]
    click.echo(f"wrote {out}: {det.n_images} images in {len(det.images)} folder(s); "
               + (", ".join(found) + "; " if found else "")
               + (f"CRS {_crs_name(proj.crs)}" if proj.crs else "no CRS (a block in its own frame)")
               + f"; stages {', '.join(s.name for s in proj.stages)}")
    for note in det.notes:
        click.echo(f"note: {note}")
    click.echo(f"edit it, then: skyrig run {out}")


def _crs_name(crs: str) -> str:
    """A CRS in a few words: its text when short (``EPSG:25832``), else its name (a WKT, e.g. the CRS carrying a
    local ENU frame)."""
    if len(crs) < 60:
        return crs
    from skyrig.geodesy.crs import resolve_crs

    return resolve_crs(crs).name


@click.command("run")
@click.argument("project", type=click.Path(), default="project.yaml")
@click.option("--from", "from_stage", default=None, metavar="STAGE",
              help="Rerun STAGE and every stage after it (the earlier ones must have run).")
@click.option("--only", default=None, metavar="STAGE", help="Run only STAGE (its inputs must have been published).")
@click.option("--force", is_flag=True, help="Rerun the selected stages even when they are up to date.")
@click.option("--dry-run", is_flag=True, help="Say which stages would run or be skipped, and why; run nothing.")
@click.option("--list-stages", is_flag=True, help="List the stages skyrig knows with their options; run nothing.")
@click.option("--live", is_flag=True,
              help="Live project mode: process the flight as it is recorded into the project's inputs (stage live, "
                   "options stages.live), publish OUTPUT/live when it is over.")
@click.option("--then-batch", is_flag=True, help="With --live: then run the project's stages.")
@click.option("--replay", "replay_src", type=click.Path(exists=True, file_okay=False), default=None,
              help="With --live: replay this recorded or simulated flight folder into the project's inputs at "
                   "--speed (a test of the chain).")
@click.option("--speed", type=float, default=1.0, show_default=True,
              help="With --replay: flight seconds per wall-clock second.")
@click.option("--serve/--no-serve", default=True, show_default=True,
              help="With --live: serve the growing map on 127.0.0.1.")
@click.option("--port", type=int, default=0, show_default=True, help="With --serve: port (0: any free port).")
def run_command(project: str, from_stage: str | None, only: str | None, force: bool, dry_run: bool,
                list_stages: bool, live: bool, then_batch: bool, replay_src: str | None, speed: float, serve: bool,
                port: int) -> None:
    """Run the stages of PROJECT (a project.yaml, or a folder holding one), each into OUTPUT/<stage>/.

    A stage whose inputs and options are unchanged since its last run is skipped; a failed stage publishes
    nothing and leaves every earlier output as it was.  Exit status: 0 ok, 1 a stage failed, 2 bad input.
    With --live, the flight is processed as it is recorded first (OUTPUT/live), then with --then-batch the stages.
    """
    from skyrig.pipeline.project import load_project
    from skyrig.pipeline.run import STAGES, plan_run, run_project

    if not live:
        for name, val in (("--then-batch", then_batch), ("--replay", replay_src)):
            if val:
                raise click.UsageError(f"{name} goes with --live")
    elif from_stage or only or dry_run or list_stages:
        raise click.UsageError("--live runs the live stage, then (--then-batch) every stage: without --from, --only, "
                               "--dry-run, --list-stages")
    if live:
        _run_live(project, replay_src, speed, serve, port)
        if not then_batch:
            return

    if list_stages:
        for st in STAGES.values():
            need = ", ".join(st.requires) or "-"
            uses = f"; uses: {', '.join(st.uses)} (when an earlier stage gives it)" if st.uses else ""
            click.echo(f"{st.name}: {st.help}\n  needs: {need}{uses}; provides: "
                       + ", ".join(f"{k} ({v})" for k, v in st.provides.items()))
            for name, opt in st.options.items():
                click.echo(f"    {name} = {opt.default!r}  ({opt.kind}) {opt.help}")
        return
    proj = load_project(project)  # with --live --then-batch: now that the flight is recorded
    if dry_run:
        for name, action, why in plan_run(proj, from_stage=from_stage, only=only, force=force):
            click.echo(f"{name:12s} {action:12s} {why}")
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from skyrig.cli import RUNNING

    console = Console(stderr=True)
    n = len(proj.stages)
    index = {s.name: k + 1 for k, s in enumerate(proj.stages)}
    # one display: a line per stage event, and a live bar for the stage that is running (its tiles, pairs ...)
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                   console=console, transient=True)
    tasks: dict[str, object] = {}

    def on_event(ev) -> None:  # type: ignore[no-untyped-def]
        k = f"[{index[ev.stage]}/{n}]"
        out = bar.console
        if ev.status == "start":
            RUNNING[0] = ev.stage  # named if a signal stops the run
            out.print(f"[bold]{k} {ev.stage}[/bold] running ({ev.message})")
            tasks[ev.stage] = bar.add_task(f"{k} {ev.stage}", total=None)
        elif ev.status == "progress":
            if ev.stage in tasks:
                bar.update(tasks[ev.stage], completed=ev.done, total=ev.total or None)  # type: ignore[arg-type]
        elif ev.status in ("done", "failed") and ev.stage in tasks:
            bar.remove_task(tasks.pop(ev.stage))  # type: ignore[arg-type]
        if ev.status == "done":
            out.print(f"{k} {ev.stage} [green]done[/green] in {ev.seconds:.1f} s -> {proj.output / ev.stage}")
        elif ev.status == "skipped":
            out.print(f"{k} {ev.stage} skipped ({ev.message})")
        elif ev.status == "not-selected":
            out.print(f"{k} {ev.stage} not selected")
        elif ev.status == "failed":
            out.print(f"{k} {ev.stage} [red]FAILED[/red]: {ev.message}")

    click.echo(f"project {proj.name} ({proj.path}): {n} stages -> {proj.output}")
    with bar:
        res = run_project(proj, from_stage=from_stage, only=only, force=force, on_event=on_event)
    if not res.ok:
        click.echo(f"error: {res.error} (earlier outputs left as they were; rerun resumes)", err=True)
        sys.exit(res.exit_code)
    ran = sum(1 for s in res.stages if s["status"] == "done")
    skipped = sum(1 for s in res.stages if s["status"] == "skipped")
    click.echo(f"{ran} stage(s) ran, {skipped} up to date; summary in {proj.output / 'run.json'}")


def _run_live(project: str, replay_src: str | None, speed: float, serve: bool, port: int) -> None:
    """``skyrig run PROJECT --live``: the live stage while the flight is recorded, published as OUTPUT/live."""
    import threading

    from skyrig.cli.live import _print_summary
    from skyrig.pipeline.live_project import flight_paths
    from skyrig.pipeline.live_run import live_spec, run_live_project
    from skyrig.pipeline.project import load_project

    if speed <= 0:
        raise click.BadParameter("must be > 0", param_hint="--speed")
    proj = load_project(project, live=True)
    paths = flight_paths(proj, live_spec(proj).options)
    rep = None
    if replay_src is not None:
        from skyrig.pipeline.live_replay import replay_flight

        paths.end.unlink(missing_ok=True)
        rep = threading.Thread(target=replay_flight, args=(replay_src, paths, speed), daemon=True,
                               name="skyrig-live-replay")
    srv: list = []

    def started(run) -> None:  # type: ignore[no-untyped-def]
        if serve:
            from skyrig.web.live import LiveServer

            srv.append(LiveServer(run.out).start())
            click.echo(f"live map (this machine only): {srv[0].url}")
        if rep is not None:
            rep.start()

    click.echo(f"project {proj.name} ({proj.path}): live, watching {paths.images} (the flight is over when "
               f"{paths.end} appears)")
    try:
        summary, folder = run_live_project(proj, say=lambda line: click.echo(line, err=True), on_start=started)
    finally:
        for s in srv:
            s.stop()
    _print_summary(summary, folder)

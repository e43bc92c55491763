"""``skyrig check``: validate a project and every input it names without running a stage."""

from __future__ import annotations

import sys

import click


@click.command("check")
@click.argument("project", type=click.Path(), default="project.yaml")
def command(project: str) -> None:
    """Open and validate every input and option of PROJECT (a project.yaml or its folder) without running any stage;
    name every problem found in one run.  Exit status: 0 nothing found, 2 problems."""
    from skyrig.pipeline.check import check_project

    rep = check_project(project)
    for w in rep.warnings:
        click.echo(f"warning: {w}", err=True)
    for e in rep.errors:
        click.echo(f"error: {e}", err=True)
    if rep.errors:
        click.echo(f"{len(rep.errors)} problem(s), {len(rep.warnings)} warning(s); {len(rep.read)} input file(s) read",
                   err=True)
        sys.exit(2)
    click.echo(f"ok: {len(rep.read)} input file(s) read, no problem found"
               + (f" ({len(rep.warnings)} warning(s))" if rep.warnings else ""))

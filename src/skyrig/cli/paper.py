"""``skyrig paper``: the tables and figures of the papers skyrig is built from, computed, into one folder."""

from __future__ import annotations

import click

from skyrig.papers import PAPERS


@click.command("paper")
@click.argument("papers", nargs=-1, required=True, type=click.Choice([*PAPERS, "all"]))
@click.option("--size", type=click.Choice(["ci", "full"]), default="ci", show_default=True,
              help="ci: the reduced scenarios the tests run (tens of seconds each); full: the papers' conditions "
                   "as far as the simulator reproduces them.")
@click.option("--out", "out", type=click.Path(file_okay=False), default="papers", show_default=True,
              help="Output folder: one sub-folder per paper (tables as CSV + JSON, figures), index.html, manifest.json.")
def command(papers: tuple[str, ...], size: str, out: str) -> None:
    """Reproduce PAPERS (000 001 002 003 004, or all): each paper's tables and figures next to its printed values.

    Exits non-zero when a paper's run raised, its module is missing or one of its checks failed (named)."""
    from skyrig.papers.publish import run_papers

    chosen = list(PAPERS) if "all" in papers else list(dict.fromkeys(papers))
    outcomes = run_papers(chosen, size, out, progress=lambda s: click.echo(s, err=True))  # type: ignore[arg-type]
    for o in outcomes:
        click.echo(f"{o.paper}  {'ok    ' if o.ok else 'FAILED'}  {o.seconds:7.1f} s  {o.title}")
    click.echo(f"index: {out}/index.html")
    bad = [o for o in outcomes if not o.ok]
    if bad:
        why = "; ".join(o.error or f"paper {o.paper}: failed checks: {', '.join(o.failed_checks)}" for o in bad)
        raise click.ClickException(why)

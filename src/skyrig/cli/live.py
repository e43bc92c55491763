"""``skyrig live FOLDER``: near-real-time DG, ortho and DSM tiles and the online boresight of a flight as it is
recorded into FOLDER (:mod:`skyrig.pipeline.live`), shown growing in a local web page."""

from __future__ import annotations

import threading

import click

from skyrig.cli._types import NONNEGATIVE


@click.command("live")
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--crs", required=True, help="Output map CRS (projected, metres), e.g. EPSG:25832.")
@click.option("--dem", "dem_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Reference DEM (GeoTIFF in the output CRS, ellipsoidal heights; e.g. a public 30 m DEM): the "
                   "orthos are projected onto it and the online boresight takes its heights from it.")
@click.option("--height", "surface_height", type=float, default=None,
              help="Height of the reference plane in the CRS's ellipsoidal heights (m), used without --dem and "
                   "outside it (default with --dem: the DEM's median).")
@click.option("--height-sigma", type=float, default=5.0, show_default=True,
              help="Standard deviation of the reference surface's heights (m).")
@click.option("-o", "--output", type=click.Path(file_okay=False), default=None,
              help="Output folder (default: FOLDER/live).")
@click.option("--cell", type=float, default=None, help="Ortho cell size (m); default: each image's GSD.")
@click.option("--window", type=click.IntRange(0), default=8, show_default=True,
              help="Exposures per online boresight adjustment (0: no online boresight).")
@click.option("--no-dsm", is_flag=True, help="No DSM tiles.")
@click.option("--stereo-head", default=None, help="Head whose consecutive images make the DSM pairs (default: the "
                                                   "head closest to nadir).")
@click.option("--image-timeout", type=NONNEGATIVE, default=20.0, show_default=True,
              help="Seconds after its event an image may take to be written completely before it is skipped.")
@click.option("--trajectory-timeout", type=NONNEGATIVE, default=20.0, show_default=True,
              help="Seconds an exposure past the trajectory's end waits for new samples before it is skipped.")
@click.option("--idle-stop", type=NONNEGATIVE, default=None,
              help="Stop after this many seconds without new input (default: run until FOLDER/flight.end or Ctrl-C).")
@click.option("--replay", "replay_src", type=click.Path(exists=True, file_okay=False), default=None,
              help="Replay this recorded or simulated flight folder into FOLDER while watching it (a test of the "
                   "chain at the flight's rate).")
@click.option("--speed", type=float, default=1.0, show_default=True,
              help="Replay speed: flight seconds per wall-clock second (1: the real exposure rate).")
@click.option("--serve/--no-serve", default=True, show_default=True, help="Serve the growing map on 127.0.0.1.")
@click.option("--port", type=int, default=0, show_default=True, help="Port on 127.0.0.1 (0: any free port).")
def command(folder, crs, dem_path, surface_height, height_sigma, output, cell, window, no_dsm, stereo_head, image_timeout,
            trajectory_timeout, idle_stop, replay_src, speed, serve, port):
    """Process the flight recorded into FOLDER as it grows (rig.yaml, trajectory.csv, events.csv, images/):
    per exposure DG, ortho tiles, DSM tiles of stereo pairs and the online boresight; latency per exposure in
    OUTPUT/latency.jsonl and a summary at the end."""
    from pathlib import Path

    from skyrig.pipeline.live import LiveConfig, LiveRun
    from skyrig.pipeline.live_replay import replay_flight

    folder_p = Path(folder)
    if surface_height is None:
        if dem_path is None:
            raise click.UsageError("give the reference surface: --dem FILE or --height H")
        import numpy as np

        from skyrig.io.dem import read_dem

        surface_height = float(np.nanmedian(read_dem(dem_path).heights))
    rep = None
    if replay_src is not None:
        if speed <= 0:
            raise click.BadParameter("must be > 0", param_hint="--speed")
        folder_p.mkdir(parents=True, exist_ok=True)
        (folder_p / "flight.end").unlink(missing_ok=True)
        import shutil

        shutil.copyfile(Path(replay_src) / "rig.yaml", folder_p / "rig.yaml")
        rep = threading.Thread(target=replay_flight, args=(replay_src, folder_p, speed), daemon=True,
                               name="skyrig-live-replay")
    cfg = LiveConfig(surface_height_m=surface_height, surface_sigma_m=height_sigma, dem_path=dem_path, crs=crs,
                     cell_m=cell,
                     dsm=not no_dsm, window=window, stereo_head=stereo_head, image_timeout_s=image_timeout,
                     trajectory_timeout_s=trajectory_timeout, idle_stop_s=idle_stop)
    run = LiveRun(folder_p, output, cfg, say=lambda line: click.echo(line, err=True))
    srv = None
    if serve:
        from skyrig.web.live import LiveServer

        srv = LiveServer(run.out).start()
        click.echo(f"live map (this machine only): {srv.url}")
    if rep is not None:
        rep.start()
    stop = threading.Event()
    try:
        summary = run.run(stop)
    except KeyboardInterrupt:
        stop.set()
        summary = run.finish()
    finally:
        if srv is not None:
            srv.stop()
    _print_summary(summary, run.out)


def _print_summary(s: dict, out) -> None:
    def med(key: str) -> str:
        v = s.get(key)
        return "-" if not v else f"median {v['median']:.2f} s, 95 % {v['p95']:.2f} s, max {v['max']:.2f} s"

    click.echo(f"{s['exposures_done']} exposures processed, {s['exposures_skipped']} skipped; between exposures "
               f"{(s.get('exposure_interval_s') or float('nan')):.2f} s (wall clock)")
    click.echo(f"ortho tiles after the last image was written: {med('ortho_latency_s')}; CPU per exposure "
               f"{med('ortho_cpu_s')}")
    click.echo(f"DSM tiles: {med('dsm_latency_s')}")
    if s.get("process_cpu_s_per_exposure") is not None:
        click.echo(f"CPU per exposure: {s['process_cpu_s_per_exposure']:.2f} s in all (online boresight "
                   f"{s.get('boresight_cpu_s_per_exposure') or 0.0:.2f} s); {s.get('caught_up', 0)} exposure(s) "
                   "caught up after a newer one")
    for h, v in (s.get("boresight_deg") or {}).items():
        sg = s["boresight_sigma_deg"][h]
        click.echo(f"online boresight {h} (deg, rotation vector, camera axes): "
                   + ", ".join(f"{a:+.4f} +- {b:.4f}" for a, b in zip(v, sg)))
    click.echo(f"tiles, latency.jsonl, boresight.jsonl, summary.json in {out}")

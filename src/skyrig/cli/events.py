"""``skyrig events --log LOG --images HEAD=FOLDER ... -o events.csv``: the camera events CSV
(docs/formats/events_csv.md) from a camera trigger log and the image folders of the rig's heads.

The log is a CSV with one row per platform exposure (trigger): a ``time`` column (seconds in the ``--time``
scale, e.g. the GNSS receiver's event marks in GPS seconds of week), optionally ``exposure`` (integer id; default
the row number) and ``beta`` (the actuated head's angle at the trigger, in ``--angles``); other columns are
ignored, ``#`` lines are comments.  Each ``--images HEAD=FOLDER`` folder holds that head's images (or
``HEAD='images/*_nadir.png'``, a glob pattern, when the heads share a folder); sorted by file name, its k-th image is the k-th trigger's, so every folder must hold exactly as many images as the log
has rows (else an error naming the head, the folder and both counts).  With ``--rig`` the heads must be the
rig's, and ``beta`` goes to its actuated heads (without ``--rig``: to the heads named by ``--actuated``).
"""

from __future__ import annotations

import click

__all__ = ["command", "events_from_log"]


def _read_log(path: str, angles: str):  # type: ignore[no-untyped-def]
    """``(time_s, exposure_id, beta_rad, lines)`` of a trigger log (see the module docstring)."""
    import csv
    import io

    import numpy as np

    from skyrig.errors import InputFormatError
    from skyrig.io._text import parse_float, read_text

    lines = read_text(path).splitlines()
    start = 0
    while start < len(lines) and (not lines[start].strip() or lines[start].lstrip().startswith("#")):
        start += 1
    if start >= len(lines):
        raise InputFormatError("no column header row", path, len(lines))
    rows = list(csv.reader(io.StringIO("\n".join(lines[start:]))))
    header = [h.strip().lower() for h in rows[0]]
    if "time" not in header:
        raise InputFormatError(f"missing column 'time' (columns: {', '.join(header)})", path, start + 1, "time")
    t, expo, beta, ln = [], [], [], []
    for k, row in enumerate(rows[1:]):
        line = start + 2 + k
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        if len(row) != len(header):
            raise InputFormatError(f"expected {len(header)} fields, found {len(row)}", path, line)
        rec = dict(zip(header, (c.strip() for c in row)))
        t.append(parse_float(rec["time"], path, line, "time"))
        if "exposure" in rec:
            try:
                expo.append(int(rec["exposure"]))
            except ValueError:
                raise InputFormatError(f"exposure id {rec['exposure']!r} is not a whole number", path, line,
                                       "exposure") from None
        beta.append(parse_float(rec["beta"], path, line, "beta") if rec.get("beta", "") != "" else np.nan)
        ln.append(line)
    if not t:
        raise InputFormatError("no trigger rows", path, start + 1)
    t_arr = np.array(t, dtype=np.float64)
    if not np.all(np.isfinite(t_arr)):
        k = int(np.flatnonzero(~np.isfinite(t_arr))[0])
        raise InputFormatError("time is not a finite number", path, ln[k], "time")
    back = np.flatnonzero(np.diff(t_arr) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise InputFormatError(f"time {t_arr[k]:.6f} does not follow {t_arr[k - 1]:.6f} (the log must be in time "
                               "order, one row per trigger)", path, ln[k], "time")
    e = np.array(expo, dtype=np.int64) if expo else np.arange(1, len(t) + 1, dtype=np.int64)
    if len(np.unique(e)) != len(e):
        _, first = np.unique(e, return_index=True)
        k = int(np.setdiff1d(np.arange(len(e)), first)[0])
        raise InputFormatError(f"exposure id {int(e[k])} appears twice", path, ln[k], "exposure")
    scale = {"deg": np.pi / 180.0, "rad": 1.0, "gon": np.pi / 200.0}[angles]
    return t_arr, e, np.array(beta, dtype=np.float64) * scale, np.array(ln, dtype=np.int64)


def _images(spec: str):  # type: ignore[no-untyped-def]
    """The image files of a folder, or of a glob pattern (``images/*_nadir.png``: heads sharing one folder), sorted
    by name."""
    import glob
    from pathlib import Path

    from skyrig.errors import InputFormatError
    from skyrig.io.image_read import IMAGE_SUFFIXES, list_images

    if not glob.has_magic(spec):
        return list_images(spec)
    found = sorted((Path(q) for q in glob.glob(spec)), key=lambda q: q.name)
    found = [q for q in found if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES]
    if not found:
        raise InputFormatError("no image file matches the pattern", spec)
    return found


def events_from_log(log: str, folders: dict[str, str], actuated: set[str], time_system: str = "gps-sow",
                    angles: str = "deg"):  # type: ignore[no-untyped-def]
    """:class:`~skyrig.trajectory.CameraEvents` from a trigger log and one image folder per head (the k-th image
    of each folder, by file name, is the k-th trigger's); ``actuated`` heads take the log's ``beta``."""
    import numpy as np

    from skyrig.errors import InputFormatError
    from skyrig.io.image_read import list_images
    from skyrig.trajectory import CameraEvents

    t, expo, beta, _ = _read_log(log, angles)
    names, heads, times, betas, ids = [], [], [], [], []
    for head, folder in folders.items():
        imgs = _images(folder)
        if len(imgs) != len(t):
            raise InputFormatError(f"head {head!r}: {len(imgs)} images in {folder} but {len(t)} triggers in the log; "
                                   "each folder must hold one image per trigger", log, None, "time")
        if head in actuated and not np.all(np.isfinite(beta)):
            raise InputFormatError(f"head {head!r} is actuated but the log has no 'beta' for every trigger", log, None,
                                   "beta")
        names += [p.name for p in imgs]
        heads += [head] * len(t)
        times.append(t)
        betas.append(beta if head in actuated else np.full(len(t), np.nan))
        ids.append(expo)
    seen: dict[str, str] = {}
    for n, h in zip(names, heads):
        if n in seen:
            raise InputFormatError(f"image name {n!r} is in the folders of heads {seen[n]!r} and {h!r}; image names "
                                   "must be unique across heads", folders[h], None, "image")
        seen[n] = h
    return CameraEvents(np.concatenate(times), np.array(heads), np.array(names), np.concatenate(betas),
                        np.concatenate(ids), time_system=time_system)


@click.command("events")
@click.option("--log", "log_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Trigger log CSV: 'time' (+ optional 'exposure', 'beta') per exposure, in time order.")
@click.option("--images", "image_specs", multiple=True, required=True, metavar="HEAD=FOLDER",
              help="A head's image folder or glob pattern (repeat per head); its k-th image by name is the k-th "
                   "trigger's.")
@click.option("--rig", "rig_path", type=click.Path(exists=True, dir_okay=False),
              help="Rig file: the heads must be its heads; beta goes to its actuated heads.")
@click.option("--actuated", default="", help="Without --rig: comma list of the heads that take the log's beta.")
@click.option("--time", "time_system", type=click.Choice(["gps-sow", "gps", "utc-sod", "utc-unix"]),
              default="gps-sow", show_default=True, help="Time scale of the log's times (as the trajectory's).")
@click.option("--angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True,
              help="Unit of the log's beta.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Events CSV to write.")
def command(log_path: str, image_specs: tuple[str, ...], rig_path: str | None, actuated: str, time_system: str,
            angles: str, output: str) -> None:
    """Camera events CSV from a trigger log and one image folder per rig head."""
    import glob
    from pathlib import Path

    from skyrig.io.events_csv import write_events_csv

    folders: dict[str, str] = {}
    for spec in image_specs:
        head, eq, folder = spec.partition("=")
        if not eq or not head.strip() or not folder.strip():
            raise click.BadParameter(f"{spec!r}: expected HEAD=FOLDER", param_hint="--images")
        if head.strip() in folders:
            raise click.BadParameter(f"head {head.strip()!r} given twice", param_hint="--images")
        if not Path(folder).is_dir() and not glob.has_magic(folder):
            raise click.BadParameter(f"{folder}: no such folder", param_hint="--images")
        folders[head.strip()] = folder
    act = {h.strip() for h in actuated.split(",") if h.strip()}
    if rig_path:
        if act:
            raise click.UsageError("--actuated goes without --rig (the rig file says which heads are actuated)")
        from skyrig.io.rig_file import read_rig

        rig = read_rig(rig_path)
        unknown = [h for h in folders if h not in rig.head_names]
        if unknown:
            raise click.BadParameter(f"head {unknown[0]!r} is not a head of {rig_path} (heads: "
                                     f"{', '.join(rig.head_names)})", param_hint="--images")
        act = {h for h in folders if rig.head(h).is_actuated}
    elif act - set(folders):
        raise click.BadParameter(f"{sorted(act - set(folders))[0]!r} has no --images folder", param_hint="--actuated")
    ev = events_from_log(log_path, folders, act, time_system, angles)
    write_events_csv(output, ev, angles=angles)
    click.echo(f"wrote {output}: {len(ev)} images of {len(folders)} heads at {len(set(ev.exposure_id.tolist()))} "
               f"exposures ({time_system})" + (f"; actuator angles for {', '.join(sorted(act))}" if act else ""))

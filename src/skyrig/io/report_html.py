"""Adjustment reports on disk: JSON (the tables of :func:`skyrig.adjust.report.adjustment_report`), a
self-contained HTML page and a residual-vector plot (PNG, matplotlib).  Every file is written atomically."""

from __future__ import annotations

import html
import io
import json
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.adjust.adjust import AdjustmentResult
from skyrig.io._text import atomic_write

__all__ = ["write_report_json", "write_report_html", "write_residual_plot", "write_report", "measure_command",
           "project_of_stage_folder", "project_stage"]

PathLike = str | os.PathLike[str]


def _clean(o: Any) -> Any:
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (np.floating, float)):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def write_report_json(path: PathLike, report: dict[str, Any]) -> None:
    """The report dict as JSON (NaN written as null)."""
    with atomic_write(path) as fh:
        json.dump(_clean(report), fh, indent=1)
        fh.write("\n")


def write_residual_plot(path: PathLike, result: AdjustmentResult, camera: int = 0, grid: int = 12,
                        scale: float | None = None) -> None:
    """Image residuals of one camera averaged on a ``grid x grid`` raster, drawn as vectors (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b = result.block
    cam = b.cameras[camera]
    img = result.residuals["image"]
    sel = (b.image_camera[b.obs_image] == camera) & (img.weight > 0)
    px, v = b.obs_pixel[sel], img.residual[sel]
    w = float(getattr(cam, "width", 0) or (np.ptp(px[:, 0]) if len(px) else 1.0))
    h = float(getattr(cam, "height", 0) or (np.ptp(px[:, 1]) if len(px) else 1.0))
    x0 = 0.0 if hasattr(cam, "width") else float(px[:, 0].min()) if len(px) else 0.0
    y0 = 0.0 if hasattr(cam, "height") else float(px[:, 1].min()) if len(px) else 0.0
    fig, ax = plt.subplots(figsize=(7, 7 * h / w if w else 5))
    if len(px):
        gx = np.clip(((px[:, 0] - x0) / w * grid).astype(int), 0, grid - 1)
        gy = np.clip(((px[:, 1] - y0) / h * grid).astype(int), 0, grid - 1)
        cell = gy * grid + gx
        n = np.bincount(cell, minlength=grid * grid)
        mx = np.bincount(cell, v[:, 0], grid * grid) / np.maximum(n, 1)
        my = np.bincount(cell, v[:, 1], grid * grid) / np.maximum(n, 1)
        cx = (np.arange(grid * grid) % grid + 0.5) * w / grid + x0
        cy = (np.arange(grid * grid) // grid + 0.5) * h / grid + y0
        ok = n > 0
        mag = np.hypot(mx[ok], my[ok])
        s = scale or (0.5 * w / grid / max(float(mag.max()) if mag.size else 1.0, 1e-12))
        ax.quiver(cx[ok], cy[ok], mx[ok] * s, my[ok] * s, angles="xy", scale_units="xy", scale=1, width=0.003)
        ax.set_title(f"{cam.name}: mean image residual per cell ({len(px)} obs), arrows x{s:.0f}")
    ax.set_xlim(x0, x0 + w)
    ax.set_ylim(y0 + h, y0)
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    ax.set_aspect("equal")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def _fmt(v: Any, nd: int = 3) -> str:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.{nd}f}"
    if isinstance(v, list):
        return " / ".join(_fmt(x, nd) for x in v)
    return html.escape(str(v))


def _table(rows: list[dict[str, Any]], cols: list[str], nd: int = 3) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(r.get(c), nd)}</td>" for c in cols) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


#: ``(project.yaml, staging folder, published folder)`` of the project stage running now (:func:`project_stage`).
_PROJECT_STAGE: ContextVar[tuple[Path, Path, Path] | None] = ContextVar("skyrig_project_stage", default=None)


@contextmanager
def project_stage(project_file: PathLike, staging: PathLike, published: PathLike) -> Iterator[None]:
    """While a project stage runs (``skyrig run``), the reports it writes in ``staging`` name ``project_file`` and
    the ``published`` folder in their ``skyrig measure`` command (:func:`measure_command`)."""
    token = _PROJECT_STAGE.set((Path(project_file).absolute(), Path(staging).absolute(), Path(published).absolute()))
    try:
        yield
    finally:
        _PROJECT_STAGE.reset(token)


def _published_folder(folder: Path) -> Path:
    """Where a stage folder is published: a staging folder ``.NAME.partial-*`` (:mod:`skyrig.io.stage`) is
    renamed to its sibling ``NAME`` when the stage ends; any other folder is itself."""
    name = folder.name
    if name.startswith(".") and ".partial-" in name:
        return folder.parent / name[1:].split(".partial-", 1)[0]
    return folder


def project_of_stage_folder(folder: PathLike, levels: int = 4) -> Path | None:
    """The ``project.yaml`` whose output folder holds the stage folder ``folder`` (published or staging): the
    first one up the folder tree (``levels`` folders) whose ``output:`` key (default ``output``) resolves to the
    stage folder's parent; None when ``folder`` is not a project stage's."""
    import yaml

    stage = _published_folder(Path(folder).absolute())
    out_dir = stage.parent.resolve()
    for d in list(stage.parents)[:levels]:
        y = d / "project.yaml"
        if not y.is_file():
            continue
        try:
            top = yaml.safe_load(y.read_text(encoding="utf-8-sig"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        text = str(top.get("output") or "output") if isinstance(top, dict) else "output"
        o = Path(text).expanduser()
        o = o if o.is_absolute() else d / o
        if o.resolve() == out_dir:
            return y
    return None


def measure_command(folder: PathLike, project: PathLike | None = None) -> str:
    """The words and the command that open ``skyrig measure`` on the control / check points of the adjustment
    written in ``folder`` (its ``ground_control.csv``), their residuals shown with them: a report cannot start the
    page's server, so it names the command.

    The command names the real paths: ``project`` (default: the ``project.yaml`` whose output holds ``folder``,
    :func:`project_of_stage_folder`, or the one of the stage running now, :func:`project_stage`) and the folder where the stage is published (a staging folder's final
    name).  Out of a project (``skyrig adjust BLOCK -o OUT``) it names the adjusted ``eo.csv`` and leaves the
    camera, images and points the block came from to the user, said in words."""
    import shlex

    pub = _published_folder(Path(folder).absolute())
    running = _PROJECT_STAGE.get()
    if project is None and running is not None and running[1] == Path(folder).absolute():
        project, pub = running[0], running[2]
    proj = Path(project).absolute() if project is not None else project_of_stage_folder(pub)
    adj = shlex.quote(str(pub))
    if proj is not None:
        return ("Measure or re-measure these points in the images (the page shows these residuals with them): "
                f"skyrig measure {shlex.quote(str(proj))} --adjustment {adj}")
    return ("Measure or re-measure these points in the images (the page shows these residuals with them): "
            f"skyrig measure --eo {shlex.quote(str(pub / 'eo.csv'))} --adjustment {adj} "
            "--camera CAMERA --images IMAGES --points POINTS (this adjustment is not a project stage: give the "
            "camera file, image folder and control points the block was made from)")


def write_report_html(path: PathLike, report: dict[str, Any], title: str = "skyrig adjustment",
                      plots: list[str] = (), folder: PathLike | None = None) -> None:
    """A self-contained HTML page of the report tables (plots referenced by relative file name); with control or
    check points and ``folder`` (where ``ground_control.csv`` is), the ``skyrig measure`` command for them."""
    r = report
    parts = [f"<h1>{html.escape(title)}</h1>", "<h2>Summary</h2>",
             _table([{"item": k, "value": v} for k, v in r["summary"].items()], ["item", "value"], 4),
             "<h2>Observation groups (variance components)</h2>",
             _table([dict(group=g, **s) for g, s in r["groups"].items()],
                    ["group", "n", "redundancy", "variance_factor", "rms"], 4)]
    for key, name in (("control", "Control points"), ("check", "Check points")):
        t = r[key]
        if t["rows"]:
            parts += [f"<h2>{name} (V = adjusted - given, m)</h2>",
                      _table(sorted(t["rows"], key=lambda x: x["VXYZ"]), ["point", "VX", "VY", "VZ", "VXYZ"]),
                      _table([t["stats"]], [k for k in ("n", "rms_m", "rms_gsd", "mean_m", "max_abs_m", "limits_m",
                                                        "within_limits") if k in t["stats"]])]
    if folder is not None and (r["control"]["rows"] or r["check"]["rows"]):
        parts.append(f"<p class='measure'>{html.escape(measure_command(folder))}</p>")
    o = r["orientation"]
    parts += ["<h2>Orientation vs GNSS/IMU</h2>",
              _table([{"item": k, "value": v} for k, v in o.items() if not isinstance(v, dict)], ["item", "value"], 5),
              "<h2>Image residuals per camera (px)</h2>",
              _table([dict(camera=c, **s) for c, s in r["images"].items()], ["camera", "n", "rms_px", "max_abs_px"])]
    if r.get("distances"):
        d = r["distances"]
        parts += ["<h2>Distances (scale bars; residual = adjusted - observed, m)</h2>",
                  _table(d["rows"], ["point_a", "point_b", "observed_m", "adjusted_m", "residual_m", "sigma_m",
                                     "normalised", "redundancy", "used"], 4),
                  _table([d["stats"]], ["n", "rms_m", "max_abs_normalised"], 4)]
    if r["rejected"]:
        parts += ["<h2>Rejected observations (data snooping)</h2>",
                  _table(r["rejected"], ["group", "label", "normalised_residual"], 2)]
    if r["warnings"]:
        parts += ["<h2>Warnings</h2><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in r["warnings"]) + "</ul>"]
    for p in plots:
        parts.append(f'<h2>Residual vectors</h2><img src="{html.escape(p)}" alt="residual vectors">')
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse;margin:8px 0}"
             "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}")
    doc = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
           f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
    with atomic_write(path) as fh:
        fh.write(doc)


def write_report(outdir: PathLike, result: AdjustmentResult, report: dict[str, Any],
                 title: str = "skyrig adjustment") -> dict[str, Path]:
    """``report.json``, ``report.html`` and ``residuals_<camera>.png`` (frame cameras) in ``outdir``."""
    d = Path(outdir)
    d.mkdir(parents=True, exist_ok=True)
    plots = []
    b = result.block
    for k, cam in enumerate(b.cameras[:8]):
        if not np.any(b.image_camera[b.obs_image] == k):
            continue
        name = f"residuals_{k}.png"
        write_residual_plot(d / name, result, k)
        plots.append(name)
    write_report_json(d / "report.json", report)
    write_report_html(d / "report.html", report, title, plots, folder=d)
    out = {"json": d / "report.json", "html": d / "report.html"}
    out.update({p: d / p for p in plots})
    return out

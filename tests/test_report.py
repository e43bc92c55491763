"""skyrig.report: the self-contained HTML report of an adjustment.

Independent answers: every checked table cell is recomputed here from the result's arrays (residuals, weights,
covariance, block values), not taken from the report code's own tables; self-containment by scanning the page
for any URL or relative source; the page rendered by headless Chromium (skipped with a reason when no Chromium
is installed) to a PNG and to a PDF.
"""

from __future__ import annotations

import base64
import io
import math
import os
import re
import shutil
import stat
import subprocess
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from skyrig.adjust import adjust
from skyrig.adjust.presets import apply_preset
from skyrig.adjust.synthetic import synthetic_block
from skyrig.camera.brown import BrownDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.report import (
    SECTION_BUILDERS,
    Figure,
    Section,
    Table,
    Column,
    build_report,
    make_section,
    register_section,
    report_data_from_adjustment,
    write_report,
)

ARCSEC = 180 / math.pi * 3600


class _Tables(HTMLParser):
    """Tables by id -> rows of cell texts (header row left out), section ids, img sources, link targets."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.sections: list[str] = []
        self.srcs: list[str] = []
        self.hrefs: list[str] = []
        self._tab: str | None = None
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):  # type: ignore[no-untyped-def]
        a = dict(attrs)
        if tag == "table":
            self._tab = a.get("id", f"anon{len(self.tables)}")
            self.tables[self._tab] = []
        elif tag == "tr" and self._tab is not None:
            self._row = []
        elif tag == "td" and self._row is not None:
            self._cell = []
        elif tag == "section":
            self.sections.append(a.get("id", ""))
        if "src" in a:
            self.srcs.append(a["src"])
        if "href" in a:
            self.hrefs.append(a["href"])

    def handle_endtag(self, tag):  # type: ignore[no-untyped-def]
        if tag == "td" and self._cell is not None and self._row is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None and self._tab is not None:
            if self._row:
                self.tables[self._tab].append(self._row)
            self._row = None
        elif tag == "table":
            self._tab = None

    def handle_data(self, data):  # type: ignore[no-untyped-def]
        if self._cell is not None:
            self._cell.append(data)


def _parse(text: str) -> _Tables:
    p = _Tables()
    p.feed(text)
    return p


def _num(cell: str) -> float:
    return float("nan") if cell == "n/a" else float(cell)


def _close(cell: str, value: float, decimals: int) -> None:
    """A cell printed with ``decimals`` equals ``value`` to half a unit of its last digit."""
    assert abs(_num(cell) - value) <= 0.5 * 10.0**-decimals + 1e-12, (cell, value)


@pytest.fixture(scope="module")
def adjusted():
    cam = FrameCamera.from_pixels("cam", 3000, 2000, 2500.0, 1499.5, 999.5, pixel_size_mm=0.004,
                                  distortion=BrownDistortion())
    b, truth = synthetic_block(seed=3, n_strips=2, n_per_strip=6, n_points=200, n_control=6, camera=cam)
    b.control_check[-2:] = True
    b2, cfg = apply_preset(b, "ba-eo-control")
    cfg = cfg.with_reliability(snooping=False)
    cfg = cfg.with_unknowns(boresight="free", intrinsics="free", intrinsic_names=("focal_mm", "ppx_mm", "ppy_mm", "k1"))
    res = adjust(b2, cfg)
    assert res.ok, res.failures
    return res


@pytest.fixture(scope="module")
def page(adjusted, tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    inp = d / "block.json"
    inp.write_text('{"format": "skyrig-block"}\n')
    data = report_data_from_adjustment(adjusted, title="synthetic block", inputs=[inp], options={"preset": "x"},
                                       created="2024-05-01T12:00:00+00:00")
    yy, xx = np.mgrid[0:120, 0:160]
    data.add(make_section("dsm", dsm=10 * np.sin(xx / 20.0) * np.cos(yy / 15.0), cell_m=0.5))
    data.add(make_section("ortho", np.random.default_rng(0).integers(0, 255, (60, 80, 3)).astype(np.uint8)))
    path = d / "report.html"
    write_report(path, data)
    return path, data, inp


def test_sections_present(page):
    path, data, _ = page
    p = _parse(path.read_text())
    for key in ("run", "summary", "calibration", "control", "orientation", "cameras", "images", "points",
                "normalised", "dsm", "ortho", "options"):
        assert f"sec-{key}" in p.sections, key
    # order on the page: the run first, the summary next, the options last; dsm after the adjustment sections
    assert p.sections[:2] == ["sec-run", "sec-summary"] and p.sections[-1] == "sec-options"
    assert p.sections.index("sec-dsm") > p.sections.index("sec-normalised")
    text = path.read_text()
    for fig in ("residual-map", "gnss-map", "image-residuals-0", "histogram", "dsm-hillshade", "ortho-preview"):
        assert f"id='fig-{fig}'" in text, fig
    assert "skyrig 0.1" in text and "2024-05-01T12:00:00+00:00" in text


def test_inputs_and_permissions(page):
    path, _, inp = page
    import hashlib

    rows = _parse(path.read_text()).tables["tab-inputs"]
    assert rows == [[str(inp), hashlib.sha256(inp.read_bytes()).hexdigest(), str(inp.stat().st_size)]]
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    assert not [f for f in path.parent.iterdir() if f.name.startswith(".")]  # no temp file left


def test_self_contained(page):
    path, _, _ = page
    text = path.read_text()
    p = _parse(text)
    assert not re.search(r"(?i)\b(https?|file|ftp):", text)
    assert not re.search(r"(?i)url\(", text) and "<script" not in text and "<link" not in text
    assert p.srcs and all(s.startswith("data:image/png;base64,") for s in p.srcs)
    assert all(h.startswith("#") for h in p.hrefs)
    for s in p.srcs:  # every embedded image is a real PNG
        png = base64.b64decode(s.split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000
    assert "@media print" in text and "@page" in text


def test_summary_numbers(adjusted, page):
    res = adjusted
    t = _parse(page[0].read_text()).tables
    rows = {r[0] + (" " + r[2] if r[2] else ""): r[1] for r in t["tab-summary"]}
    b = res.block
    _close(rows["sigma0 (a-posteriori, unit weight)"], res.sigma0, 4)
    _close(rows["sigma0 of an image observation px"], res.sigma0 * 0.5, 4)  # a-priori 0.5 px
    _close(rows["sigma0 of an image observation um"], res.sigma0 * 0.5 * 4.0, 4)  # 4 um pixels
    cp, chk = res.initial.control_point, res.initial.control_check
    v = b.point_xyz[cp] - res.initial.control_xyz
    for k, ax in enumerate("XYZ"):
        _close(rows[f"RMS control points {ax} (n = {int((~chk).sum())}) m"], np.sqrt(np.mean(v[~chk, k] ** 2)), 4)
        _close(rows[f"RMS check points {ax} (n = {int(chk.sum())}) m"], np.sqrt(np.mean(v[chk, k] ** 2)), 4)
    g = res.residuals["gnss"].residual
    for k, ax in enumerate("XYZ"):
        _close(rows[f"RMS photo position vs GNSS {ax} m"], np.sqrt(np.mean(g[:, k] ** 2)), 4)
        _close(rows[f"GPS block shift {ax} (mean GNSS - adjusted) m"], -g[:, k].mean(), 4)
    imu = np.degrees(res.residuals["imu"].residual)
    for k, ax in enumerate(("rx", "ry", "rz")):
        _close(rows[f"RMS photo attitude vs IMU {ax} deg"], np.sqrt(np.mean(imu[:, k] ** 2)), 4)


def test_control_table(adjusted, page):
    res = adjusted
    t = _parse(page[0].read_text()).tables
    cp, chk = res.initial.control_point, res.initial.control_check
    v = res.block.point_xyz[cp] - res.initial.control_xyz
    names = res.block.point_name[cp]
    for key, sel in (("tab-control", ~chk), ("tab-check", chk)):
        got = {r[0]: r[1:] for r in t[key]}
        assert set(got) == set(names[sel])
        for n, vv in zip(names[sel], v[sel]):
            for k in range(3):
                _close(got[n][k], vv[k], 4)
            _close(got[n][3], np.linalg.norm(vv), 4)


def test_calibration_with_units_and_sigmas(adjusted, page):
    res = adjusted
    text = page[0].read_text()
    t = _parse(text).tables
    lab = {lab: i for i, lab in enumerate(res.layout.labels)}
    Q = res.covariance.Qcc
    # boresight: camera-axis rows; value and sigma in degrees and arc-seconds
    bore = {(r[0], r[1]): r for r in t["tab-boresight"]}
    for k, c in enumerate("xyz"):
        r = bore[("nadir", f"about camera {c}")]
        val = res.block.head_boresight[0, k]
        sig = res.sigma0 * np.sqrt(Q[lab[("boresight", "nadir", f"r{c}")]] [lab[("boresight", "nadir", f"r{c}")]])
        _close(r[3], np.degrees(val), 6)
        _close(r[4], val * ARCSEC, 2)
        _close(r[5], np.degrees(sig), 6)
        _close(r[6], sig * ARCSEC, 2)
        assert r[7] == "estimated"
    assert "(arcsec)" in text and "(deg)" in text
    # interior orientation: mm and px, sigma from the covariance
    cam = res.block.cameras[0]
    io_rows = {r[1]: r for r in t["tab-interior"] if r[0] == cam.name}
    i = lab[("intrinsics", cam.name, "focal_mm")]
    sig_f = res.sigma0 * np.sqrt(Q[i, i])
    assert io_rows["focal_mm"][5] == "mm"
    assert abs(float(io_rows["focal_mm"][3]) - cam.focal_mm) <= 1e-6 * cam.focal_mm
    assert abs(float(io_rows["focal_mm"][4]) - sig_f) <= 0.01 * sig_f
    _close(io_rows["focal_mm"][6], cam.focal_mm / cam.pixel_size_mm, 3)
    _close(io_rows["focal_mm"][7], sig_f / cam.pixel_size_mm, 3)
    assert io_rows["k1"][5] == "mm^-2" and io_rows["k2"][8] == "fixed"
    # GNSS/IMU system: datum shift estimated with sigma in metres, lever arm held
    sysr = {(r[0], r[1]): r for r in t["tab-gnss-imu"]}
    j = lab[("datum_shift", "gnss", "Z")]
    _close(sysr[("GNSS datum shift", "Z")][3], res.block.datum_shift[2], 4)
    _close(sysr[("GNSS datum shift", "Z")][4], res.sigma0 * np.sqrt(Q[j, j]), 4)
    assert sysr[("lever arm (body frame)", "x")][5] == "m" and sysr[("lever arm (body frame)", "x")][6] == "fixed"


def test_per_image_and_camera_tables(adjusted, page):
    res = adjusted
    b = res.block
    t = _parse(page[0].read_text()).tables
    img = res.residuals["image"]
    act = img.weight > 0
    rows = {r[0]: r for r in t["tab-images"]}
    assert len(rows) == b.n_images
    ps = res.pose_sigma
    for i, name in enumerate(b.image_name):
        sel = act & (b.obs_image == i)
        r = img.residual[sel]
        assert int(rows[name][4]) == int(sel.sum())
        _close(rows[name][5], np.sqrt(np.mean(r[:, 0] ** 2)), 3)
        _close(rows[name][6], np.sqrt(np.mean(r[:, 1] ** 2)), 3)
        _close(rows[name][7], np.hypot(r[:, 0], r[:, 1]).max(), 3)
        _close(rows[name][10], ps[b.image_station[i], 2], 4)
        _close(rows[name][11], np.degrees(ps[b.image_station[i], 3]) * 3600, 1)
    cam = t["tab-cameras"][0]
    r = img.residual[act]
    assert cam[0] == "cam" and int(cam[1]) == b.n_images and int(cam[2]) == int(act.sum())
    _close(cam[3], np.sqrt(np.mean(r[:, 0] ** 2)), 3)
    _close(cam[6], np.sqrt(np.mean(r[:, 0] ** 2)) * 4.0, 2)  # 4 um pixels


def test_point_precision_and_normalised(adjusted, page):
    res = adjusted
    t = _parse(page[0].read_text()).tables
    ps = res.point_sigma
    ps = ps[np.isfinite(ps).all(axis=1)]
    stats = {r[0]: r for r in t["tab-points"]}
    for k in range(3):
        _close(stats["median"][1 + k], np.median(ps[:, k]), 4)
        _close(stats["max"][1 + k], ps[:, k].max(), 4)
    _close(stats["RMS"][4], np.sqrt(np.mean((ps**2).sum(1))), 4)
    norm = {r[0]: r for r in t["tab-normalised"]}
    for g, gr in res.residuals.items():
        if gr.normalised is None:
            continue
        w = gr.normalised[(gr.weight > 0) & ~gr.constant].reshape(-1)
        assert int(norm[g][1]) == w.size
        _close(norm[g][4], np.abs(w).max(), 2)


def test_failures_on_top(adjusted):
    data = report_data_from_adjustment(adjusted, created="2024-01-01T00:00:00+00:00")
    data.failures = ["did not converge (maximum iterations; 50 iterations)"]
    data.warnings = ["point p1 left out: behind image i3"]
    text = build_report(data)
    body = text[text.index("<body>"):]
    assert body.index("id='failures'") < body.index("id='warnings'") < body.index("<section")
    assert "FAILED" in body[:body.index("<section")]


def test_registry_for_later_stages(adjusted):
    @register_section("test-extra", order=15)
    def _extra(value: float) -> Section:
        return Section("test-extra", "Extra stage", [Table("extra", "Extra", [Column("v", "m", 2)], [[value]])])

    try:
        data = report_data_from_adjustment(adjusted, created="2024-01-01T00:00:00+00:00")
        data.add(make_section("test-extra", 1.234))
        keys = [s.key for s in data.sections]
        assert keys.index("summary") < keys.index("test-extra") < keys.index("calibration")
        assert _parse(build_report(data)).tables["tab-extra"] == [["1.23"]]
        data.add(Section("test-extra", "Replaced", [Figure("f", "c", b"\x89PNG\r\n\x1a\n")]))
        assert [s.title for s in data.sections if s.key == "test-extra"] == ["Replaced"]
    finally:
        SECTION_BUILDERS.pop("test-extra", None)
    with pytest.raises(KeyError, match="no report section"):
        make_section("nope")


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    return None


def _run_chromium(exe: str, user_dir: Path, *args: str) -> None:
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={user_dir}", *args]
    subprocess.run(cmd, check=True, capture_output=True, timeout=180)


@pytest.mark.skipif(_chromium() is None, reason="no Chromium installed (chromium / google-chrome not on PATH); "
                                               "the rendering check needs a browser")
def test_renders_in_headless_chromium(page, tmp_path):
    from matplotlib.image import imread

    exe = _chromium()
    html_path = page[0]
    shot = tmp_path / "shot.png"
    _run_chromium(exe, tmp_path / "profile", f"--screenshot={shot}", "--window-size=1280,4000",
                  html_path.resolve().as_uri())
    img = imread(io.BytesIO(shot.read_bytes()), format="png")
    assert img.shape[:2] == (4000, 1280)
    grey = img[..., :3].mean(axis=2)
    dark = grey < 0.5  # text, table rules, plot lines
    assert dark.mean() > 0.01, "the page rendered (almost) blank"
    rows_with_ink = (grey < 0.9).any(axis=1)
    assert rows_with_ink[:3000].mean() > 0.3  # content down the page, not only a header
    colour = np.abs(img[..., 0] - img[..., 2]) > 0.2  # the plots' colour maps (blue/red) and the warning box
    assert colour.sum() > 500
    pdf = tmp_path / "report.pdf"
    _run_chromium(exe, tmp_path / "profile", f"--print-to-pdf={pdf}", "--no-pdf-header-footer",
                  html_path.resolve().as_uri())
    raw = pdf.read_bytes()
    assert raw[:5] == b"%PDF-"
    pages = len(re.findall(rb"/Type\s*/Page[^s]", raw))
    assert pages >= 3, pages


def test_uav_report_self_calibration(tmp_path):
    """The adjust-uav page: the UAV block summary and the camera's self-calibration with sigmas."""
    import sys
    from dataclasses import asdict

    from skyrig.adjust.report import adjustment_report
    from skyrig.pipeline.uav import UavConfig, adjust_uav_block
    from skyrig.report import report_data_from_uav

    sys.path.insert(0, str(Path(__file__).parent))
    try:
        from test_uav_adjust import _sim_block
    finally:
        sys.path.pop(0)
    inp, _ = _sim_block(n_points=500)
    cfg = UavConfig(gnss_sigma_m=(0.5, 0.5, 1.0), pixel_sigma_px=0.3, attitude_sigma_deg=5.0, pnp_threshold_px=4.0)
    res = adjust_uav_block(inp, cfg)
    rep = adjustment_report(res.adjustment)
    rep["uav"] = dict(res.summary, config=asdict(cfg), attitude_check=res.attitude_check)
    path = tmp_path / "report.html"
    write_report(path, report_data_from_uav(res, rep, inputs=[], options=rep["uav"]["config"]))
    p = _parse(path.read_text())
    assert "sec-uav" in p.sections and "sec-calibration" in p.sections
    a = res.adjustment
    cam = a.block.cameras[0]
    lab = {lab: i for i, lab in enumerate(a.layout.labels)}
    rows = {r[1]: r for r in p.tables["tab-interior"]}
    for nm, unit in (("focal_mm", "mm"), ("ppx_mm", "mm"), ("k1", "1")):
        i = lab[("intrinsics", cam.name, nm)]
        sig = a.sigma0 * np.sqrt(a.covariance.Qcc[i, i])
        assert rows[nm][5] == unit and rows[nm][8] == "estimated"
        assert abs(float(rows[nm][4]) - sig) <= 0.01 * sig
    att = {r[0]: r[1] for r in p.tables["tab-attitude-check"]}
    assert att == {k: str(v.get("metadata", "")) for k, v in res.attitude_check.items()}


def test_control_section_names_the_measure_command(adjusted, tmp_path):
    """The report cannot start ``skyrig measure``'s server: its control section (and the plain page of
    ``skyrig.io.report_html``) names the command.  Out of a project it names this report's eo.csv and folder
    (``--eo``, ``--adjustment``) and asks for the rest in words; that command parses, and the folder resolves to
    the ground_control.csv written next to the report."""
    import html as html_mod
    import shlex

    import click

    from skyrig.adjust.report import adjustment_report
    from skyrig.cli.measure import _ground_control, command
    from skyrig.io.report_html import write_report as write_plain_report
    from skyrig.report import write_adjustment_report

    rep = adjustment_report(adjusted)
    full = write_adjustment_report(tmp_path / "full", adjusted, rep, "synthetic")["html"]
    plain = write_plain_report(tmp_path / "plain", adjusted, rep)["html"]
    for page_path in (full, plain):
        text = html_mod.unescape(page_path.read_text())
        assert "skyrig measure PROJECT" not in text
        m = re.search(r"skyrig measure --eo (\S+) --adjustment (\S+)", text)
        assert m, page_path
        args = shlex.split(m.group(0))[2:]
        assert Path(args[1]) == page_path.parent.absolute() / "eo.csv"
        assert Path(args[3]) == page_path.parent.absolute()
        (page_path.parent / "ground_control.csv").write_text("name,x,y,z\n")
        (page_path.parent / "eo.csv").write_text("")
        ctx = command.make_context("measure", args)
        assert Path(ctx.params["adjustment"]) == page_path.parent and Path(ctx.params["eo_path"]).name == "eo.csv"
        assert _ground_control(Path(ctx.params["adjustment"])) == page_path.parent / "ground_control.csv"
    (tmp_path / "empty").mkdir()
    with pytest.raises(click.BadParameter, match="no ground_control.csv in the folder"):
        _ground_control(tmp_path / "empty")


@pytest.mark.parametrize("output_key", ["", "output: results\n"])
def test_measure_command_finds_the_project_of_a_stage_folder(tmp_path, output_key):
    """A stage folder (published or staging, ``OUTPUT/.adjust.partial-*``) under the project's output (the
    default ``output`` or a relative ``output:`` key): the command names that project.yaml and the published
    folder, and the measure command's own parser takes it; a project.yaml whose output is elsewhere is not it."""
    import shlex

    from skyrig.cli.measure import command
    from skyrig.io.report_html import measure_command

    root = tmp_path / "my flight"
    outdir = root / ("results" if "results" in output_key else "output")
    root.mkdir()
    (root / "project.yaml").write_text("format: skyrig-project\nversion: 1\n" + output_key)
    staging = outdir / ".adjust.partial-k3j2"
    staging.mkdir(parents=True)
    for folder in (staging, outdir / "adjust"):
        words = measure_command(folder)
        args = shlex.split(words.split("skyrig measure ", 1)[1])
        assert args == [str(root / "project.yaml"), "--adjustment", str(outdir / "adjust")], words
    (outdir / "adjust").mkdir()
    assert Path(command.make_context("measure", args).params["project"]) == root / "project.yaml"
    (root / "project.yaml").write_text("format: skyrig-project\nversion: 1\noutput: other\n")
    assert "--eo" in measure_command(staging) and str(root / "project.yaml") not in measure_command(staging)


def test_report_written_by_a_project_stage_names_the_project(adjusted, tmp_path):
    """In a project run the report is written in the stage's staging folder and the runner says which project
    runs it (:func:`skyrig.io.report_html.project_stage`): the page names that project.yaml and the published
    folder, also for an absolute ``output:`` elsewhere."""
    import html as html_mod
    import shlex

    from skyrig.adjust.report import adjustment_report
    from skyrig.io.report_html import project_stage
    from skyrig.report import write_adjustment_report

    root, outdir = tmp_path / "my flight", tmp_path / "elsewhere"
    root.mkdir()
    (root / "project.yaml").write_text(f"format: skyrig-project\nversion: 1\noutput: {outdir}\n")
    staging = outdir / ".adjust.partial-k3j2"
    staging.mkdir(parents=True)
    with project_stage(root / "project.yaml", staging, outdir / "adjust"):
        page = write_adjustment_report(staging, adjusted, adjustment_report(adjusted), "synthetic")["html"]
    text = html_mod.unescape(page.read_text())
    m = re.search(r"skyrig measure (.+?)(?:<|$)", text, re.M)
    assert m and "PROJECT" not in text, text[:2000]
    assert shlex.split(m.group(1)) == [str(root / "project.yaml"), "--adjustment", str(outdir / "adjust")]

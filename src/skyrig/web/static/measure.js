// skyrig measure: the page. Talks to the local server (skyrig/web/server.py) with the session token; draws the
// predictions, ellipses, measurements and the proposal over an OpenSeadragon deep-zoom viewer.
// Pixel convention of the server: column right, row down, origin at the CENTRE of the top-left pixel; OpenSeadragon's
// image coordinates have their origin at the top-left CORNER: osd = skyrig + 0.5.
"use strict";
(function () {
  const TOKEN = document.querySelector('meta[name="skyrig-token"]').content;
  const K95 = 2.4477; // sqrt of chi-square(2 dof) 95 %
  // the prediction the page centres on: by intersection (two or more measurements), else along the one measured
  // ray (depth from the surveyed point), else from the surveyed point
  const centredOn = (p) => [p.intersection, p.ray].find((q) => q && q.column !== null) || p.ground;
  const withToken = (u) => u + (u.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(TOKEN);
  const $ = (id) => document.getElementById(id);
  const body = document.body;
  const S = { points: [], point: null, pstate: null, pred: null, proposal: null, click: null, saved: 0 };

  async function api(path, payload) {
    const init = payload === undefined ? {} : {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(payload) };
    const r = await fetch(withToken(path), init);
    const j = await r.json().catch(() => ({ error: "HTTP " + r.status }));
    if (!r.ok) throw new Error(j.error || ("HTTP " + r.status));
    return j;
  }
  function status(text, isError) {
    $("status").textContent = text;
    $("status").style.color = isError ? "#b00" : "#444";
    if (isError) body.dataset.lastError = text;
  }

  const viewer = OpenSeadragon({
    element: $("viewer"), showNavigationControl: false, maxZoomPixelRatio: 24, animationTime: 0.25,
    gestureSettingsMouse: { clickToZoom: false, dblClickToZoom: true }, imageSmoothingEnabled: false,
    crossOriginPolicy: false, preserveImageSizeOnResize: true,
  });
  const P = (c, r) => viewer.viewport.imageToViewerElementCoordinates(new OpenSeadragon.Point(c + 0.5, r + 0.5));
  window.skyrigMeasure = {
    imageToElement: (c, r) => { const p = P(c, r); return { x: p.x, y: p.y }; },
    state: S,
  };

  // ---------------------------------------------------------------------------------------------- lists
  async function loadPoints() {
    const j = await api("/api/points");
    S.points = j.points;
    $("summary").textContent = `${j.points.length} ground points, ${j.n_images} images; saving to ${j.output}` +
      ` as ${j.operator}`;
    const ul = $("points");
    ul.replaceChildren();
    for (const p of j.points) {
      const li = document.createElement("li");
      li.id = "pt-" + p.name;
      li.dataset.point = p.name;
      li.textContent = `${p.name} (${p.role}${p.code !== null ? ", code " + p.code : ""}) ${p.measured_in}/${p.predicted_in}` +
        (p.adjustment ? `  v ${p.adjustment.v3d_m} m` : "");
      if (p.flagged) li.classList.add("flag");
      if (S.point === p.name) li.classList.add("sel");
      li.addEventListener("click", () => selectPoint(p.name));
      ul.appendChild(li);
    }
  }

  async function selectPoint(name) {
    S.point = name;
    S.pred = null;
    S.proposal = null;
    for (const li of $("points").children) li.classList.toggle("sel", li.dataset.point === name);
    await refreshPoint();
    $("detect").disabled = false;
  }

  async function refreshPoint() {
    S.pstate = await api("/api/point/" + encodeURIComponent(S.point));
    const st = S.pstate;
    $("point-title").textContent = `${st.point} (${st.role})`;
    let info = `x ${st.xyz[0].toFixed(3)}  y ${st.xyz[1].toFixed(3)}  z ${st.xyz[2].toFixed(3)}\n${st.frame}`;
    if (st.intersection) {
      const d = st.intersection.minus_ground_enu_m;
      info += `\nintersection of ${st.intersection.n_images} images minus ground: E ${d[0]} N ${d[1]} U ${d[2]} m` +
        ` (sigma ${st.intersection.sigma_m.join(", ")} m)`;
    }
    if (st.adjustment) {
      const a = st.adjustment;
      info += `\nadjustment (${a.role}): adjusted - given ${a.v_m.join(", ")} m (|v| ${a.v3d_m} m, sigma ` +
        `${a.sigma_m.join(", ")} m)`;
    }
    if (st.note) info += "\n" + st.note;
    $("point-info").textContent = info;
    const byImage = {};
    for (const m of st.measurements) byImage[m.image] = m;
    const ul = $("images");
    ul.replaceChildren();
    for (const p of st.predictions) {
      const li = document.createElement("li");
      li.id = "img-" + p.index;
      li.dataset.image = p.image;
      const m = byImage[p.image];
      let text = `${p.image}  q ${p.quality}`;
      if (p.target_px !== null) text += `  target ${p.target_px} px`;
      if (st.code !== null && p.target_px !== null && p.target_px < 2.5) {
        li.classList.add("small"); text += " (too small)"; li.title = "the coded target's dot is predicted under 2.5 px here: its code cannot be read"; }
      if (m) {
        const v = m.vs_intersection || m.vs_ground;
        text += `  \u2713 ${m.method}  d ${v.dcolumn}, ${v.drow}`;
        if (m.flag) li.classList.add("flag");
      }
      if (!p.file) { li.classList.add("missing"); text += "  (no file)"; }
      li.textContent = text;
      if (S.pred && S.pred.image === p.image) li.classList.add("sel");
      li.addEventListener("click", () => selectImage(p));
      ul.appendChild(li);
    }
    if (S.pred) S.pred = st.predictions.find((p) => p.image === S.pred.image) || S.pred;
    $("delete").disabled = !(S.pred && byImage[S.pred.image]);
    body.dataset.point = st.point;
    body.dataset.pointLoads = String(Number(body.dataset.pointLoads || 0) + 1);  // for tests: a refresh is complete
    draw();
  }

  // ---------------------------------------------------------------------------------------------- viewer
  async function selectImage(pred) {
    if (!pred.file) { status(`${pred.image}: no image file found in the image folders`, true); return; }
    S.pred = pred;
    S.proposal = null;
    S.click = null;
    $("accept").disabled = $("keep").disabled = true;
    body.dataset.imageReady = "0";
    for (const li of $("images").children) li.classList.toggle("sel", li.dataset.image === pred.image);
    const info = await api("/api/image/" + pred.index);
    const src = {
      width: info.width, height: info.height, tileSize: info.tileSize, tileOverlap: info.tileOverlap,
      minLevel: info.minLevel, maxLevel: info.maxLevel,
      getTileUrl: (l, x, y) => withToken(`/api/tile/${info.index}/${l}/${x}_${y}.jpg`),
    };
    viewer.addOnceHandler("open", () => {
      const g = centredOn(S.pred);
      const half = Math.max(48, 4 * K95 * (g.a || 0));
      const rect = viewer.viewport.imageToViewportRectangle(g.column + 0.5 - half, g.row + 0.5 - half, 2 * half, 2 * half);
      viewer.viewport.fitBounds(rect, true);
      const item = viewer.world.getItemAt(0);
      const done = () => { body.dataset.imageReady = "1"; body.dataset.image = pred.image; draw(); };
      if (item.getFullyLoaded()) done();
      else item.addHandler("fully-loaded-change", (e) => { if (e.fullyLoaded) done(); });
      draw();
    });
    viewer.open(src);
    $("delete").disabled = !S.pstate.measurements.some((m) => m.image === pred.image);
    status(`${pred.image}: click on the point`);
  }

  // the search radius of a proposal: the user's value, else the 95 % ellipse's major semi-axis of the prediction
  // the page centres on (centredOn), at least 3 px and at most the server's bound (200 px)
  const MAX_SEARCH = 200;
  function searchRadius() {
    const typed = $("search").value.trim();
    if (typed !== "") return Number(typed);  // sent as typed: the server refuses what is not in [0, 200]
    const g = centredOn(S.pred);
    if (g.a === null) return 0;
    return Math.min(MAX_SEARCH, Math.max(3, Math.round(K95 * g.a * 10) / 10));
  }

  viewer.addHandler("canvas-click", async (e) => {
    if (!e.quick || !S.pred) return;
    e.preventDefaultAction = true;
    const p = viewer.viewport.viewerElementToImageCoordinates(e.position);
    const col = p.x - 0.5, row = p.y - 0.5;
    S.click = { column: col, row: row };
    try {
      const prop = await api("/api/propose", { point: S.point, image: S.pred.image, column: col, row: row,
                                                method: $("method").value, search_px: searchRadius() });
      S.proposal = prop;
      body.dataset.proposal = JSON.stringify(prop);
      $("keep").disabled = false;
      // a refused target refinement: said in red; Accept only for what was still refined (least-squares matching)
      $("accept").disabled = Boolean(prop.refused) && !prop.refined;
      status(`proposal ${prop.column}, ${prop.row} (${prop.method}${prop.refined ? ", refined" : ""}, ` +
             `sigma ${prop.sigma_px} px, search ${prop.search_px} px): ${prop.note}. ` +
             (prop.refused ? "Refused: " + prop.refused + ". Keep click stores the click; a new click moves it."
                           : "Enter accepts, a new click moves it."), Boolean(prop.refused));
      draw();
    } catch (err) { status(String(err.message || err), true); }
  });

  async function accept(asClicked) {
    if (!S.proposal || !S.pred) return;
    const p = asClicked ? { column: S.click.column, row: S.click.row, method: "click", refined: false, sigma_px: null }
                        : S.proposal;
    try {
      S.pstate = await api("/api/accept", { point: S.point, image: S.pred.image, column: p.column, row: p.row,
                                            method: p.method, refined: p.refined, sigma_px: p.sigma_px });
      S.saved += 1;
      S.proposal = null;
      $("accept").disabled = $("keep").disabled = true;
      status(`saved ${S.point} in ${S.pred.image}`);
      await refreshPoint();
      await loadPoints();
      body.dataset.saved = String(S.saved);  // after the lists are rebuilt
    } catch (err) { status(String(err.message || err), true); }
  }
  $("accept").addEventListener("click", () => accept(false));
  $("keep").addEventListener("click", () => accept(true));
  $("delete").addEventListener("click", async () => {
    try {
      await api("/api/delete", { point: S.point, image: S.pred.image });
      status(`deleted ${S.point} in ${S.pred.image}`);
      await refreshPoint();
      await loadPoints();
    } catch (err) { status(String(err.message || err), true); }
  });
  $("detect").addEventListener("click", async () => {
    try {
      const j = await api("/api/detect", { point: S.point, accept: true });
      status(`${j.found.length} target(s) detected and stored for ${S.point}` + (j.skipped.length ?
             `; ${j.skipped.length} image(s) passed over: ` + j.skipped.map((k) => `${k.image}: ${k.reason}`).join("; ")
             : ""), j.skipped.length > 0);
      await refreshPoint();
      await loadPoints();
    } catch (err) { status(String(err.message || err), true); }
  });
  document.addEventListener("keydown", (e) => {
    if (e.key === "Enter" && !$("accept").disabled) accept(false);
  });

  // ---------------------------------------------------------------------------------------------- drawing
  const NS = "http://www.w3.org/2000/svg";
  function el(tag, attrs) {
    const e = document.createElementNS(NS, tag);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    return e;
  }
  function cross(svg, c, r, color, size, diag) {
    const p = P(c, r);
    const d = size;
    const seg = diag ? [[-d, -d, d, d], [-d, d, d, -d]] : [[-d, 0, d, 0], [0, -d, 0, d]];
    for (const s of seg) svg.appendChild(el("line", { x1: p.x + s[0], y1: p.y + s[1], x2: p.x + s[2], y2: p.y + s[3],
                                                     stroke: color, "stroke-width": 1.5 }));
  }
  function ellipse(svg, g, color) {
    if (g.a === null || g.column === null) return;
    const t = (g.angle_deg || 0) * Math.PI / 180, pts = [];
    for (let k = 0; k <= 48; k++) {
      const u = 2 * Math.PI * k / 48, x = K95 * g.a * Math.cos(u), y = K95 * g.b * Math.sin(u);
      const p = P(g.column + x * Math.cos(t) - y * Math.sin(t), g.row + x * Math.sin(t) + y * Math.cos(t));
      pts.push(`${p.x.toFixed(1)},${p.y.toFixed(1)}`);
    }
    svg.appendChild(el("polyline", { points: pts.join(" "), fill: "none", stroke: color, "stroke-width": 1.2 }));
  }
  function draw() {
    const svg = $("overlay");
    svg.replaceChildren();
    if (!S.pred || !viewer.world.getItemCount()) return;
    const g = S.pred.ground;
    if (g.column !== null) { ellipse(svg, g, "#2a7de1"); cross(svg, g.column, g.row, "#2a7de1", 8, false); }
    const i = [S.pred.intersection, S.pred.ray].find((q) => q && q.column !== null);
    if (i) { ellipse(svg, i, "#1a9c3a"); cross(svg, i.column, i.row, "#1a9c3a", 8, false); }
    const m = S.pstate && S.pstate.measurements.find((x) => x.image === S.pred.image);
    if (m) { const p = P(m.column, m.row);
      svg.appendChild(el("circle", { cx: p.x, cy: p.y, r: 7, fill: "none", stroke: "#d0202e", "stroke-width": 1.5 }));
      cross(svg, m.column, m.row, "#d0202e", 3, false); }
    if (S.proposal) cross(svg, S.proposal.column, S.proposal.row, "#f0c000", 7, true);
  }
  viewer.addHandler("update-viewport", draw);

  loadPoints().then(async () => {
    const next = S.points.find((p) => p.measured_in < Math.min(2, p.predicted_in));  // continue where one stopped
    if (next) await selectPoint(next.name);
    body.dataset.ready = "1";
  }).catch((err) => status(String(err.message || err), true));
})();

// skyrig live: a Leaflet map of the run's XYZ tiles, refreshed as the run writes new ones.
"use strict";
(function () {
  const token = document.querySelector('meta[name="skyrig-token"]').content;
  const q = "?token=" + encodeURIComponent(token);
  const map = L.map("map", { zoomControl: true, attributionControl: false });
  map.setView([0, 0], 2);
  let layers = null, fitted = false, lastDone = -1;
  map.setMaxZoom(22);

  // Layers only once the run's zoom levels and extent are known, and never below the coarsest level written: at a
  // world view a layer whose tiles start at zoom 12 would ask for millions of tiles.
  function makeLayers(zooms, b) {
    map.setMinZoom(zooms[0]);
    map.setMaxZoom(zooms[zooms.length - 1] + 3);
    const opts = { minZoom: zooms[0], maxZoom: zooms[zooms.length - 1] + 3, minNativeZoom: zooms[0],
                   maxNativeZoom: zooms[zooms.length - 1], tileSize: 256, noWrap: true,
                   bounds: [[b[1], b[0]], [b[3], b[2]]] };
    const ortho = L.tileLayer("/tiles/ortho/{z}/{x}/{y}.png" + q, opts).addTo(map);
    const dsm = L.tileLayer("/tiles/dsm/{z}/{x}/{y}.png" + q,
                            Object.assign({}, opts, { maxNativeZoom: zooms[zooms.length - 2] || zooms[0], opacity: 0.6 }));
    L.control.layers(null, { "ortho": ortho, "DSM (height colours)": dsm }, { collapsed: false }).addTo(map);
    return { ortho: ortho, dsm: dsm };
  }

  function fmt(v) { return v === null || v === undefined ? "" : Number(v).toFixed(2); }

  function show(st) {
    if (st.zooms && st.bounds_lonlat && !fitted) {
      const b = st.bounds_lonlat;
      map.fitBounds([[b[1], b[0]], [b[3], b[2]]]);
      fitted = true;
      layers = makeLayers(st.zooms, b);
    }
    if (layers && st.n_done !== lastDone) {   // new tiles: reload what is shown
      layers.ortho.redraw();
      if (map.hasLayer(layers.dsm)) layers.dsm.redraw();
      lastDone = st.n_done;
    }
    document.getElementById("summary").textContent =
      st.n_done + " exposures done, " + (st.n_skipped || 0) + " skipped";
    document.getElementById("summary").dataset.done = String(st.n_done);
    const bs = st.boresight_deg || {};
    document.getElementById("boresight").textContent = Object.keys(bs).length ?
      "online boresight (deg): " + Object.keys(bs).map(function (h) {
        return h + " " + bs[h].map(function (v) { return v.toFixed(4); }).join(" ");
      }).join("; ") : "online boresight: first window pending";
    const ul = document.getElementById("reported");
    ul.innerHTML = "";
    (st.reported || []).forEach(function (line) {
      const li = document.createElement("li"); li.textContent = line; ul.appendChild(li);
    });
    const tb = document.getElementById("exposures");
    tb.innerHTML = "";
    (st.exposures || []).slice().reverse().forEach(function (e) {
      const tr = document.createElement("tr");
      [e.exposure, e.state, fmt(e.ortho_s), fmt(e.dsm_s)].forEach(function (v) {
        const td = document.createElement("td"); td.textContent = v; tr.appendChild(td);
      });
      tb.appendChild(tr);
    });
  }

  function poll() {
    fetch("/api/status" + q, { cache: "no-store" }).then(function (r) { return r.json(); })
      .then(show).catch(function () {}).finally(function () { setTimeout(poll, 1000); });
  }
  poll();
})();

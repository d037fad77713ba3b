// The sign map: the service's vector tiles (GET /api/v1/tiles/{z}/{x}/{y}.mvt, through the
// dashboard's same-origin pass-through, which adds the session's key server-side), drawn by
// Leaflet.VectorGrid as SVG. A point with count 1 is a sign; a larger count is a cluster of that
// many (low zoom, or a crowded tile): clicking it zooms in. The legend above the map (map.html)
// draws the same circles, and lists the classes in view in their colours.
"use strict";
(function () {
  const el = document.getElementById("map");
  const status = document.getElementById("map-status");
  const legendClasses = document.getElementById("legend-classes");
  const map = L.map(el, {preferCanvas: false});
  Signmap.addTiles(map, el.dataset.tileUrl);

  function popup(p) {
    const rows = Object.entries(p).filter(([k, v]) => typeof v !== "object" || v === null)
      .map(([k, v]) => `<tr><th>${Signmap.escape(k)}</th><td>${Signmap.escape(v)}</td></tr>`);
    const evidence = p.evidence ? `<pre>${Signmap.escape(JSON.stringify(p.evidence, null, 1))}</pre>` : "";
    return `<table class="popup">${rows.join("")}</table>${evidence}`;
  }

  async function evidence(shown, id) {
    // The whole map sign with its evidence (member journey signs): GET /signs/{id}.
    const answer = await fetch(`/admin/api/signs/${encodeURIComponent(id)}`, {credentials: "same-origin"});
    if (!answer.ok) return;
    const body = await answer.json();
    const props = body.properties || {};
    const kept = Object.fromEntries(["evidence", "members"].filter(k => k in props).map(k => [k, props[k]]));
    const p = Object.assign({}, props, {evidence: Object.keys(kept).length ? kept : null});
    delete p.members; delete p.cov_enu;
    if (shown.isOpen()) shown.setContent(popup(p));
  }

  // CSS class of each sign class drawn, for the legend's list of the classes in view.
  const classTokens = new Map();
  function classToken(cls) {
    const token = "class-" + String(cls).replace(/[^A-Za-z0-9_-]/g, "_");
    classTokens.set(token, cls);
    return token;
  }

  // A circle near a tile's edge is drawn by each tile it reaches into, so counts go by feature.
  function featureToken(p) {
    return "feature-" + String(p.id).replace(/[^A-Za-z0-9_-]/g, "_");
  }
  function distinct(selector) {
    return new Set([...el.querySelectorAll(selector)].map(
      (node) => [...node.classList].find((c) => c.startsWith("feature-")))).size;
  }

  // The radii, strokes included, stay within what a tile reaches out for (SIGN_RADIUS_PX and
  // CLUSTER_RADIUS_PX of app/service/db/map_tiles.py), and the legend (map.html) draws these.
  function style(p) {
    if (p.count > 1) {
      return {radius: Math.min(22, 7 + 2.5 * Math.log2(p.count)), fill: true, fillOpacity: 0.75,
              fillColor: "#555", color: "#fff", weight: 2,
              className: `sign-cluster ${featureToken(p)}`};
    }
    return {radius: 7, fill: true, fillOpacity: 0.9, fillColor: Signmap.classColor(p.class),
            color: "#222", weight: 1,
            className: `sign-marker state-${p.state || "journey"} ${classToken(p.class)} ` +
                 featureToken(p)};
  }

  function showClassesInView() {
    const shown = [...classTokens].filter(([token]) => el.querySelector(`.sign-marker.${token}`))
      .map(([, cls]) => cls).sort();
    legendClasses.innerHTML = shown.length ? " (" + shown.map(cls =>
      `<svg width="12" height="12" aria-hidden="true"><circle cx="6" cy="6" r="5" ` +
      `fill="${Signmap.classColor(cls)}" stroke="#222" stroke-width="1"/></svg> ` +
      Signmap.escape(cls)).join(", ") + ")" : "";
  }

  // Leaflet asks a clicked small circle for its position (getLatLng); VectorGrid 1.3's tile-drawn
  // circles have none, so they are told to answer with the mouse's position instead.
  const SignGrid = L.VectorGrid.Protobuf.extend({
    _createLayer(feat, pxPerExtent) {
      const layer = L.VectorGrid.Protobuf.prototype._createLayer.call(this, feat, pxPerExtent);
      layer.getLatLng = null;
      return layer;
    },
  });
  const signs = new SignGrid("/admin/api/tiles/{z}/{x}/{y}.mvt", {
    rendererFactory: L.svg.tile, interactive: true, maxNativeZoom: 22, maxZoom: 22,
    fetchOptions: {credentials: "same-origin"},
    vectorTileLayerStyles: {signs: style},
  }).addTo(map);

  signs.on("click", (e) => {
    const p = e.layer.properties;
    const at = e.latlng;
    if (p.count > 1) {
      map.setView(at, Math.min(map.getZoom() + 2, 22));
      return;
    }
    const shown = L.popup({maxWidth: 420, maxHeight: 320}).setLatLng(at)
      .setContent(popup(p)).openOn(map);
    evidence(shown, p.id);
  });
  signs.on("loading", () => { status.textContent = "loading…"; });
  signs.on("load", () => {
    const n = distinct(".sign-marker");
    const clusters = distinct(".sign-cluster");
    status.textContent = `${n} signs in view` + (clusters ? ` and ${clusters} cluster${clusters > 1 ? "s" : ""} (zoom in)` : "");
    showClassesInView();
  });

  async function start() {
    // Start where there are signs: a one-sign page of the whole world finds a place.
    const answer = await fetch("/admin/api/signs?bbox=-180,-90,180,90&limit=1", {credentials: "same-origin"});
    const body = answer.ok ? await answer.json() : {features: []};
    if (body.features.length) {
      const [lon, lat] = body.features[0].geometry.coordinates;
      map.setView([lat, lon], 17);
    } else {
      map.setView([49.0, 8.4], 5);
    }
  }
  start();
})();

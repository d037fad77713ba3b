// The sign map: the viewport drives a bbox query of the public GET /api/v1/signs (through the
// dashboard's same-origin pass-through, which adds the session's key server-side).
"use strict";
(function () {
  const el = document.getElementById("map");
  const status = document.getElementById("map-status");
  const map = L.map(el, {preferCanvas: false});
  Signmap.addTiles(map, el.dataset.tileUrl);
  const layer = L.layerGroup().addTo(map);
  const LIMIT = 2000;  // a city's worth; beyond it the status line asks to zoom in
  const markers = new Map();
  let generation = 0;

  function popup(p) {
    const rows = Object.entries(p).filter(([k, v]) => typeof v !== "object" || v === null)
      .map(([k, v]) => `<tr><th>${Signmap.escape(k)}</th><td>${Signmap.escape(v)}</td></tr>`);
    const evidence = p.evidence ? `<pre>${Signmap.escape(JSON.stringify(p.evidence, null, 1))}</pre>` : "";
    const journey = p.journey_id ? `<a href="/admin/journeys/${encodeURIComponent(p.journey_id)}">journey</a>` : "";
    return `<table class="popup">${rows.join("")}</table>${evidence}${journey}`;
  }

  async function evidence(marker, f) {
    // The map sign's evidence (member journey signs), where the map serves GET /signs/{id}.
    if (f.evidenceLoaded) return;
    f.evidenceLoaded = true;
    const answer = await fetch(`/admin/api/signs/${encodeURIComponent(f.id)}`, {credentials: "same-origin"});
    if (!answer.ok) return;
    const body = await answer.json();
    const props = body.properties || {};
    const shown = Object.fromEntries(["evidence", "members"].filter(k => k in props).map(k => [k, props[k]]));
    const p = Object.assign({}, f.properties, {evidence: Object.keys(shown).length ? shown : props});
    marker.setPopupContent(popup(p));
  }

  async function load() {
    const b = map.getBounds();
    const bbox = [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()]
      .map((v, i) => Math.max(i % 2 ? -90 : -180, Math.min(i % 2 ? 90 : 180, v)).toFixed(6)).join(",");
    const mine = ++generation;
    status.textContent = "loading…";
    const answer = await fetch(`/admin/api/signs?bbox=${bbox}&limit=${LIMIT}`, {credentials: "same-origin"});
    if (mine !== generation) return;
    if (!answer.ok) { status.textContent = `map query failed (${answer.status})`; return; }
    const body = await answer.json();
    // Markers already shown stay (with any open popup); only the difference is redrawn.
    const seen = new Set();
    for (const f of body.features) {
      seen.add(f.id);
      if (markers.has(f.id)) continue;
      const [lon, lat] = f.geometry.coordinates;
      const p = f.properties;
      const marker = Signmap.marker(lat, lon, p.class, `state-${p.state || "journey"}`)
        .bindPopup(popup(p), {maxWidth: 420, maxHeight: 320}).addTo(layer);
      marker.on("popupopen", () => evidence(marker, f));
      markers.set(f.id, marker);
    }
    for (const [id, marker] of markers) {
      if (!seen.has(id)) { layer.removeLayer(marker); markers.delete(id); }
    }
    status.textContent = `${body.features.length} signs in view` + (body.next || body.features.length >= LIMIT ? " (more: zoom in)" : "");
  }

  async function start() {
    // Start on the newest signs: an unbounded-but-small query finds where there is data.
    const answer = await fetch("/admin/api/signs?bbox=-180,-90,180,90&limit=1", {credentials: "same-origin"});
    const body = answer.ok ? await answer.json() : {features: []};
    if (body.features.length) {
      const [lon, lat] = body.features[0].geometry.coordinates;
      map.setView([lat, lon], 17);
    } else {
      map.setView([49.0, 8.4], 5);
    }
  }
  map.on("moveend", load);
  start();
})();

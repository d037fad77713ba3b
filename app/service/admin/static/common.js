// Shared by the map pages: tiles that may be unreachable, and one colour per sign class.
"use strict";
window.Signmap = {
  addTiles(map, url) {
    // Without tiles (offline) the map stays a plain background; markers need no tiles.
    const layer = L.tileLayer(url, {maxZoom: 22, maxNativeZoom: 19,
      attribution: "&copy; OpenStreetMap contributors"});
    let failed = 0;
    layer.on("tileerror", () => {
      failed += 1;
      map.getContainer().classList.add("no-tiles");
    });
    layer.addTo(map);
    return layer;
  },
  classColor(cls) {
    let h = 0;
    for (const c of String(cls)) h = (h * 31 + c.charCodeAt(0)) % 360;
    return `hsl(${h}, 75%, 42%)`;
  },
  marker(lat, lon, cls, extraClass) {
    const color = Signmap.classColor(cls);
    return L.circleMarker([lat, lon], {radius: 7, color: "#222", weight: 1, fillColor: color,
      fillOpacity: 0.9, className: `sign-marker ${extraClass || ""}`});
  },
  escape(text) {
    const div = document.createElement("div");
    div.textContent = text == null ? "" : String(text);
    return div.innerHTML;
  },
};

// The journey's GPS track, its estimated (aligned) trajectory and its signs on a small map.
"use strict";
(function () {
  const el = document.getElementById("journey-map");
  const data = JSON.parse(document.getElementById("journey-data").textContent);
  const map = L.map(el);
  Signmap.addTiles(map, el.dataset.tileUrl);
  const bounds = [];
  if (data.track.length) {
    L.polyline(data.track, {color: "#1565c0", weight: 3, className: "gps-track"}).addTo(map);
    bounds.push(...data.track);
  }
  if (data.estimated.length) {
    L.polyline(data.estimated, {color: "#e65100", weight: 2, dashArray: "6 4",
                                className: "estimated-track"}).addTo(map);
    bounds.push(...data.estimated);
  }
  for (const s of data.signs) {
    Signmap.marker(s.lat, s.lon, s.cls, "journey-sign")
      .bindPopup(`<b>${Signmap.escape(s.cls)}</b> track ${Signmap.escape(s.track)}<br>σ ${s.std_m.toFixed(2)} m
        <br><a href="#sign-${encodeURIComponent(s.track)}">crops</a>`).addTo(map);
    bounds.push([s.lat, s.lon]);
  }
  if (bounds.length) map.fitBounds(bounds, {padding: [20, 20], maxZoom: 21});
  else map.setView([0, 0], 2);
})();

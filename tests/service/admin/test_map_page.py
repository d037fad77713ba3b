"""The dashboard's sign map: a legend that draws the circles as the map does, and circles whole at
tile edges (each tile is drawn on its own, so a tile must hold every circle that reaches into it).
Tiles are decoded and drawn here with the map's own sizes (admin/static/map.js, ``style``)."""

from __future__ import annotations

import math
import re
from datetime import datetime, timezone
from html.parser import HTMLParser

import numpy as np
import pytest

from app.service.db.map_tiles import (CLUSTER_RADIUS_PX, EXTENT, SIGN_RADIUS_PX, TILE_PX, Tile,
                                      decode)
from app.service.db.models import MapSignRow
from app.service.db.session import session_scope
from tests.utils.stack import ADMIN_KEY, auth, sqlite_stack

T0 = datetime(2026, 11, 1, 8, 0, tzinfo=timezone.utc)


def drawn_radius_px(count: int) -> float:
    """A circle's radius on the map, as map.js's ``style`` draws it (checked below)."""
    return 7.0 if count == 1 else min(22.0, 7.0 + 2.5 * math.log2(count))


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data")


class _Circles(HTMLParser):
    def __init__(self):
        super().__init__()
        self.circles: list[dict[str, str]] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.add(attrs["id"])
        if tag == "circle":
            self.circles.append(attrs)


def test_the_legend_draws_the_circles_as_the_map_does(stack):
    with stack.client() as client:
        client.post("/admin/login", data={"key": ADMIN_KEY})
        page = client.get("/admin/map")
        script = client.get("/admin/static/app/map.js").text
    assert page.status_code == 200
    legend = page.text.split('id="map-legend"')[1].split("</p>")[0]
    assert "a sign, in its class's colour" in legend and "a cluster of" in legend
    parsed = _Circles()
    parsed.feed(page.text)
    assert {"map-legend", "legend-classes"} <= parsed.ids  # map.js lists the classes in view there
    sign = next(c for c in parsed.circles if c.get("class") == "legend-sign")
    clusters = [c for c in parsed.circles if c.get("class") == "legend-cluster"]

    # The map's style, read from the script the page runs.
    style = script.split("function style(p)")[1].split("\n  }\n")[0]
    cluster_style, sign_style = style.split("return", 2)[1:]
    cap, base, per_doubling = map(float, re.search(
        r"Math\.min\((\d+), (\d+) \+ ([\d.]+) \* Math\.log2\(p\.count\)\)", cluster_style).groups())
    assert (cap, base, per_doubling) == (22, 7, 2.5) and "radius: 7," in sign_style
    assert 'color: "#222", weight: 1' in sign_style and "fillOpacity: 0.9" in sign_style
    assert 'fillColor: "#555", color: "#fff", weight: 2' in cluster_style

    assert (sign["r"], sign["stroke"], sign["stroke-width"], sign["fill-opacity"]) == (
        "7", "#222", "1", "0.9")
    assert len(clusters) >= 3
    for c in clusters:
        assert float(c["r"]) == drawn_radius_px(int(c["data-count"]))
        assert (c["fill"], c["stroke"], c["stroke-width"]) == ("#555", "#fff", "2")
    assert int(clusters[-1]["data-count"]) >= 2 ** ((cap - base) / per_doubling), \
        "the largest swatch is the largest circle drawn"
    # A tile reaches out as far as the circles do, strokes included.
    assert drawn_radius_px(1) + 0.5 <= SIGN_RADIUS_PX and cap + 1 <= CLUSTER_RADIUS_PX


def _add_sign(url: str, sign_id: str, lon: float, lat: float) -> None:
    with session_scope(url) as session:
        session.add(MapSignRow(id=sign_id, cls="stop", lat_deg=lat, lon_deg=lon, alt_m=110.0,
                               cov_enu=[[0.25, 0, 0], [0, 0.25, 0], [0, 0, 1.0]], std_m=0.5,
                               n_journeys=2, n_observations=2, first_seen_at=T0,
                               last_seen_at=T0, state="confirmed", evidence={}))


def _lonlat(tile: Tile, px: float, py: float) -> tuple[float, float]:
    """Inverse Web Mercator of a point in ``tile``, in screen pixels of the 256 px tile."""
    n = 2 ** tile.z
    lon = (tile.x + px / TILE_PX) / n * 360.0 - 180.0
    lat = math.degrees(math.atan(math.sinh(math.pi * (1 - 2 * (tile.y + py / TILE_PX) / n))))
    return lon, lat


def _render(client, tile: Tile) -> tuple[np.ndarray, list[dict]]:
    """The tile drawn as the map draws it: each feature a filled disc of its radius (stroke
    included), on a TILE_PX square; the pixels outside the tile are not drawn."""
    answer = client.get(f"/api/v1/tiles/{tile.z}/{tile.x}/{tile.y}.mvt", headers=auth(ADMIN_KEY))
    assert answer.status_code == 200
    layers = decode(answer.content)
    features = layers["signs"]["features"] if "signs" in layers else []
    yy, xx = np.mgrid[0:TILE_PX, 0:TILE_PX] + 0.5
    image = np.zeros((TILE_PX, TILE_PX), dtype=bool)
    for f in features:
        x, y = np.asarray(f["geometry"]["coordinates"], float) * TILE_PX / EXTENT
        count = f["properties"]["count"]
        reach = drawn_radius_px(count) + (0.5 if count == 1 else 1.0)
        image |= (xx - x) ** 2 + (yy - y) ** 2 <= reach ** 2
    return image, features


@pytest.mark.parametrize("z, n_signs", [(17, 1), (10, 2)], ids=["sign", "cluster"])
def test_a_circle_at_a_tile_edge_is_drawn_whole_by_both_tiles(stack, z, n_signs):
    """Signs 3 px west of the edge between two tiles: the eastern tile draws the part of their
    circle (a sign's at z17, a cluster's at z10) that reaches into it; a sign in the middle of the
    western tile stays out of the eastern one."""
    west = Tile(z, 550 * 2 ** (z - 10), 360 * 2 ** (z - 10))
    east = Tile(z, west.x + 1, west.y)
    for k in range(n_signs):
        _add_sign(stack.url, f"edge-{k}", *_lonlat(west, TILE_PX - 3 - 0.01 * k, 100))
    _add_sign(stack.url, "middle", *_lonlat(west, 40, 200))
    with stack.client() as client:
        west_image, west_features = _render(client, west)
        east_image, east_features = _render(client, east)
    counts = sorted(f["properties"]["count"] for f in west_features)
    assert counts == ([1, 1] if z == 17 else [1, 2])  # z10: the edge pair is one cluster
    assert west_image[100, TILE_PX - 3]
    assert east_image.any(), "the eastern tile draws its part of the circle"
    rows, cols = np.nonzero(east_image)
    assert cols.max() < drawn_radius_px(n_signs) and abs(np.median(rows) - 100) <= 1
    # A cluster's id is its smallest member's.
    edge = [f for f in east_features if f["properties"]["id"] == "edge-0"]
    assert len(east_features) == len(edge) == 1, "the middle sign is not the eastern tile's"
    assert edge[0]["properties"]["count"] == n_signs
    west_edge = next(f for f in west_features if f["properties"]["id"] == "edge-0")
    # The same circle: one pixel of the 256 is EXTENT/256 tile units.
    x_west, y_west = west_edge["geometry"]["coordinates"]
    x_east, y_east = edge[0]["geometry"]["coordinates"]
    assert abs(x_east + EXTENT - x_west) <= 1 and abs(y_east - y_west) <= 1

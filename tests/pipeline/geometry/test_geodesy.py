import math

import numpy as np
import pytest
from pyproj import Geod

from app.pipeline.geometry.geodesy import LocalFrame, frame_at

KARLSRUHE = (49.0110123, 8.4183456, 112.3)
GEOD = Geod(ellps="WGS84")


def _fixes_around(lat0, lon0, radius_m: float, n: int, seed: int):
    """n WGS84 fixes within radius_m of (lat0, lon0), from geodesic forward steps."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(-180.0, 180.0, n)
    dist = rng.uniform(0.0, radius_m, n)
    lon, lat, _ = GEOD.fwd(np.full(n, lon0), np.full(n, lat0), az, dist)
    return np.asarray(lat), np.asarray(lon), rng.uniform(-50.0, 150.0, n)


@pytest.mark.parametrize("origin", [KARLSRUHE, (-33.8688, 151.2093, 58.0),
                                    (64.1466, -21.9426, 0.0)])
def test_enu_round_trip_to_a_millimetre_over_kilometres(origin):
    frame = frame_at(*origin)
    lat, lon, alt = _fixes_around(origin[0], origin[1], 5000.0, 200, seed=1)
    xyz = frame.to_local(lat, lon, alt)
    assert np.abs(xyz[:, :2]).max() > 3000.0  # the test really spans kilometres
    lat2, lon2, alt2 = frame.to_geodetic(xyz)
    _, _, horizontal_m = GEOD.inv(lon, lat, lon2, lat2)
    assert np.max(horizontal_m) < 1e-3
    assert np.max(np.abs(alt2 - alt)) < 1e-3


def test_enu_axes_and_origin():
    frame = frame_at(*KARLSRUHE)
    np.testing.assert_allclose(frame.to_local(KARLSRUHE[0], KARLSRUHE[1], KARLSRUHE[2]),
                               [[0.0, 0.0, 0.0]], atol=1e-6)
    lon_n, lat_n, _ = GEOD.fwd(KARLSRUHE[1], KARLSRUHE[0], 0.0, 100.0)
    lon_e, lat_e, _ = GEOD.fwd(KARLSRUHE[1], KARLSRUHE[0], 90.0, 100.0)
    # Geodesic steps are on the ellipsoid; 112 m above it they are longer by a factor 1 + h/R.
    stretch = 1.0 + KARLSRUHE[2] / 6.37e6
    north = frame.to_local(lat_n, lon_n, KARLSRUHE[2])[0] / stretch
    east = frame.to_local(lat_e, lon_e, KARLSRUHE[2])[0] / stretch
    assert north[1] == pytest.approx(100.0, abs=1e-3) and abs(north[0]) < 1e-3
    assert east[0] == pytest.approx(100.0, abs=1e-3) and abs(east[1]) < 1e-3
    # The ellipsoid falls away below the tangent plane by about d^2 / 2R.
    assert north[2] == pytest.approx(-100.0**2 / (2 * 6.37e6), abs=2e-4)
    up = frame.to_local(KARLSRUHE[0], KARLSRUHE[1], KARLSRUHE[2] + 10.0)[0]
    np.testing.assert_allclose(up, [0.0, 0.0, 10.0], atol=1e-6)


def test_enu_distances_agree_with_geodesic_over_a_kilometre():
    frame = frame_at(KARLSRUHE[0], KARLSRUHE[1], None)
    lat, lon, _ = _fixes_around(KARLSRUHE[0], KARLSRUHE[1], 500.0, 60, seed=2)
    xyz = frame.to_local(lat, lon)  # on the ellipsoid (altitude 0), up to 1 km apart
    i, j = np.triu_indices(len(lat), k=1)
    _, _, geodesic_m = GEOD.inv(lon[i], lat[i], lon[j], lat[j])
    chord_m = np.linalg.norm(xyz[i] - xyz[j], axis=1)
    assert geodesic_m.max() > 900.0
    assert np.max(np.abs(chord_m - geodesic_m)) < 0.01


def test_missing_altitude_means_origin_height():
    frame = frame_at(*KARLSRUHE)
    xyz = frame.to_local([KARLSRUHE[0]], [KARLSRUHE[1]], [math.nan])
    np.testing.assert_allclose(xyz, [[0.0, 0.0, 0.0]], atol=1e-6)
    assert frame_at(49.0, 8.0, None).alt0_m == 0.0
    assert frame_at(49.0, 8.0, math.nan).alt0_m == 0.0


def test_mercator_round_trip_and_scale():
    frame = frame_at(*KARLSRUHE, kind="mercator")
    assert frame == LocalFrame(KARLSRUHE[0], KARLSRUHE[1], KARLSRUHE[2], "mercator")
    lat, lon, alt = _fixes_around(KARLSRUHE[0], KARLSRUHE[1], 5000.0, 200, seed=3)
    xyz = frame.to_local(lat, lon, alt)
    np.testing.assert_allclose(frame.to_local(*KARLSRUHE), [[0.0, 0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(xyz[:, 2], alt - KARLSRUHE[2], atol=1e-9)
    lat2, lon2, alt2 = frame.to_geodetic(xyz)
    _, _, horizontal_m = GEOD.inv(lon, lat, lon2, lat2)
    assert np.max(horizontal_m) < 1e-3
    np.testing.assert_allclose(alt2, alt, atol=1e-9)
    # The paper's eq. 3: x = s r lon (radians) with s = cos(lat0), r = 6378137 m.
    s = math.cos(math.radians(KARLSRUHE[0]))
    expected_x = s * 6378137.0 * np.radians(lon - KARLSRUHE[1])
    np.testing.assert_allclose(xyz[:, 0], expected_x, atol=1e-6)
    # Scaled spherical Mercator stays within ~0.5 % of true distances near the origin.
    _, _, geodesic_m = GEOD.inv(np.full(len(lat), KARLSRUHE[1]), np.full(len(lat), KARLSRUHE[0]),
                                lon, lat)
    planar_m = np.linalg.norm(xyz[:, :2], axis=1)
    far = geodesic_m > 100.0
    assert np.max(np.abs(planar_m[far] / geodesic_m[far] - 1.0)) < 5e-3

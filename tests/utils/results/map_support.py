"""A small synthetic world for the map-fusion tests: a straight road heading east with signs on both
sides, and journeys over it as the pipeline would return them (truth + per-journey GPS offset +
per-sign noise, aligned camera poses looking down the road), stored and fused through the same
``fusion.store_and_fuse`` the job calls."""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone

import numpy as np

from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import (Calibration, CameraModel, JourneyResult, Sign, SignObservation)
from app.service.jobs import fusion, state
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow

CAMERA = CameraModel(64, 48, 50.0, 51.0, 31.5, 23.5, -0.1, 0.01)
CLASSES = ("stop", "yield", "speed_50")
# Camera axes in ENU when heading east: x right = south, y down, z forward = east (columns).
R_WORLD_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
M_PER_DEG_LAT = 111_320.0
T0 = datetime(2026, 11, 1, 8, 0, tzinfo=timezone.utc)


@dataclass
class World:
    lat0: float
    lon0: float
    alt0: float = 100.0
    # track id -> (class, east, north, up) metres in the world's ENU frame
    signs: dict[str, tuple[str, float, float, float]] = field(default_factory=dict)

    @property
    def frame(self):
        return frame_at(self.lat0, self.lon0, self.alt0)

    def latlonalt(self, xyz_enu: np.ndarray) -> tuple[float, float, float]:
        lat, lon, alt = self.frame.to_geodetic(np.asarray(xyz_enu, float).reshape(1, 3))
        return float(lat[0]), float(lon[0]), float(alt[0])

    def error_m(self, track: str, lat: float, lon: float, alt: float | None) -> float:
        xyz = self.frame.to_local([lat], [lon], [alt])[0]
        return float(np.linalg.norm(xyz[:2] - np.array(self.signs[track][1:3])))


def make_world(n_signs: int = 6, lat0: float | None = None) -> World:
    """Signs every 20 m, alternating sides of the road, in a place unique to the caller (the
    PostgreSQL test database is shared by the session)."""
    lat0 = 20.0 + secrets.randbelow(400_000) / 10_000.0 if lat0 is None else lat0
    world = World(lat0, 10.0 + secrets.randbelow(400_000) / 10_000.0)
    for i in range(n_signs):
        world.signs[str(i)] = (CLASSES[i % 3], 20.0 + 20.0 * i, 5.0 if i % 2 else -5.0, 2.5)
    return world


def journey_result(world: World, rng: np.random.Generator, *, offset_enu_m=None,
                   gps_std_m: float = 0.7, sign_std_m: float = 0.3,
                   skip: tuple[str, ...] = (), only: tuple[str, ...] | None = None,
                   road_end_m: float | None = None) -> JourneyResult:
    """What the pipeline would return for one drive along the road: every sign (but ``skip``; only
    ``only`` when given) displaced by one GPS offset plus its own noise, and the aligned poses."""
    offset = (np.array([*rng.normal(0.0, gps_std_m, 2), 0.0]) if offset_enu_m is None
              else np.asarray(offset_enu_m, float))
    # Facings come from their own stream, seeded by the offset, so that the position draws (which
    # the fusion tests' realisations depend on) stay those of before facings existed.
    facing_rng = np.random.default_rng(np.frombuffer(offset.tobytes(), dtype=np.uint32))
    signs = []
    for track, (cls, e, n, u) in world.signs.items():
        if track in skip or (only is not None and track not in only):
            continue
        xyz = np.array([e, n, u]) + offset + np.array([*rng.normal(0.0, sign_std_m, 2), 0.0])
        lat, lon, alt = world.latlonalt(xyz)
        # Facing the drivers coming along the road (+x, east) from the west, give or take 10 deg.
        signs.append(Sign(track, cls, xyz, lat, lon, alt, sign_std_m, 0.5,
                          [SignObservation("000000", (1.0, -0.5, 12.0))],
                          facing_deg=float(270.0 + facing_rng.normal(0.0, 10.0))))
    road_end_m = 20.0 * len(world.signs) + 40.0 if road_end_m is None else road_end_m
    xs = np.arange(-30.0, road_end_m, 2.0)
    T_world_cam = np.tile(np.eye(4), (len(xs), 1, 1))
    T_world_cam[:, :3, :3] = R_WORLD_CAM
    T_world_cam[:, :3, 3] = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 1.5)], 1) + offset
    return JourneyResult(
        calibration=Calibration(CAMERA, "self", n_images=5, n_registered=5,
                                reprojection_error_px=0.4, rotation_deg=35.0),
        signs=signs, rejected=[], timings_s={},
        trajectory_frame_ids=[f"{i:06d}" for i in range(len(xs))],
        trajectory_T_world_cam=T_world_cam,
        origin_lat_lon_alt=(world.lat0, world.lon0, world.alt0))


def insert_done_journey(settings, journey_data, journey_id: str, day: int,
                        result: JourneyResult, known_camera: CameraModel | None = None) -> None:
    """A journey row captured ``day`` days after T0, claimed and finished with ``result`` through
    the job's own store+fuse."""
    url = settings.effective_database_url
    with session_scope(url) as session:
        session.add(JourneyRow(id=journey_id, owner_key_id=None, camera_id="test-cam",
                            captured_at=(T0 + timedelta(days=day)).isoformat(),
                            bundle_sha256=f"{day:04d}" + "0" * 60, bundle_bytes=1,
                            status="queued", progress=0.0, n_frames=5, attempts=0))
    with session_scope(url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    assert attempt is not None
    assert fusion.store_and_fuse(url, journey_id, attempt, journey_data, result,
                                     {"total_s": 1.0}, known_camera, settings)


def store_only(settings, journey_data, journey_id: str, day: int, result: JourneyResult) -> None:
    """Like ``insert_done_journey`` but without fusing (a job that stored and then died)."""
    url = settings.effective_database_url
    with session_scope(url) as session:
        session.add(JourneyRow(id=journey_id, owner_key_id=None, camera_id="test-cam",
                            captured_at=(T0 + timedelta(days=day)).isoformat(),
                            bundle_sha256=f"{day:04d}" + "1" * 60, bundle_bytes=1,
                            status="queued", progress=0.0, n_frames=5, attempts=0))
    with session_scope(url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    with session_scope(url) as session:
        assert fusion.store_journey(session, journey_id, attempt, journey_data, result,
                                        {"total_s": 1.0}, None, settings)


def map_sign_errors_m(features: list[dict], truth: dict) -> list[float]:
    """Distance (m) from each fused map sign feature to the nearest true sign of a rendered
    journey's truth (map signs have no track id)."""
    origin = truth["origin"]
    frame = frame_at(origin["lat"], origin["lon"], origin["alt_m"])
    true = frame.to_local([s["lat"] for s in truth["signs"]], [s["lon"] for s in truth["signs"]],
                          [s["alt_m"] for s in truth["signs"]])
    errors = []
    for feature in features:
        lon, lat, *alt = feature["geometry"]["coordinates"]
        xyz = frame.to_local([lat], [lon], [alt[0] if alt else None])[0]
        dims = 3 if alt else 2
        errors.append(float(np.min(np.linalg.norm(true[:, :dims] - xyz[:dims], axis=1))))
    return errors

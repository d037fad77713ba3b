"""Conversions between the fusion domain values (``app.fusion``) and the service's rows."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from typing import Any

import numpy as np

from app.fusion import JourneyCoverage, JourneySign, MapSign
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import CameraModel, JourneyResult
from app.service.db.models import (JourneyRow, CoverageRow,
                                JourneySignRow, MapSignRow)


def journey_sign(row: JourneySignRow, journey_key: str, captured_at_s: float) -> JourneySign:
    # The pipeline reports one isotropic 1-sigma; fusion adds the journey's GPS term itself.
    return JourneySign(sign_id=row.id, journey_key=journey_key, cls=row.cls, lat_deg=row.lat_deg,
                       lon_deg=row.lon_deg, alt_m=row.alt_m,
                       cov_enu=np.eye(3) * float(row.std_m) ** 2, captured_at=captured_at_s,
                       facing_deg=row.facing_deg)


def coverage_row(journey: JourneyRow, journey_key: str, captured_at_s: float,
                 result: JourneyResult) -> CoverageRow:
    T_world_cam = np.asarray(result.trajectory_T_world_cam, dtype=float).reshape(-1, 4, 4)
    origin = tuple(float(v) for v in result.origin_lat_lon_alt)
    box: dict[str, float | None] = dict.fromkeys(
        ("min_lat_deg", "min_lon_deg", "max_lat_deg", "max_lon_deg"))
    if len(T_world_cam):
        lat, lon, _ = frame_at(*origin).to_geodetic(T_world_cam[:, :3, 3])
        box = {"min_lat_deg": float(np.min(lat)), "min_lon_deg": float(np.min(lon)),
               "max_lat_deg": float(np.max(lat)), "max_lon_deg": float(np.max(lon))}
    cam = result.calibration.camera
    return CoverageRow(
        journey_id=journey.id, journey_key=journey_key, captured_at_s=captured_at_s,
        origin_lat_deg=origin[0], origin_lon_deg=origin[1], origin_alt_m=origin[2],
        camera={"width": cam.width, "height": cam.height, **cam.params()},
        frame_ids=list(result.trajectory_frame_ids),
        poses=T_world_cam[:, :3, :4].reshape(-1, 12).tolist(), **box)


def coverage(row: CoverageRow, detected_sign_ids: frozenset[str]) -> JourneyCoverage:
    poses = np.asarray(row.poses, dtype=float).reshape(-1, 3, 4)
    T_world_cam = np.tile(np.eye(4), (len(poses), 1, 1))
    T_world_cam[:, :3, :4] = poses
    return JourneyCoverage(
        journey_key=row.journey_key, captured_at=row.captured_at_s, T_world_cam=T_world_cam,
        origin_lat_lon_alt=(row.origin_lat_deg, row.origin_lon_deg, row.origin_alt_m),
        camera=CameraModel(**row.camera), detected_sign_ids=detected_sign_ids)


def _utc(unix_s: float) -> datetime:
    return datetime.fromtimestamp(unix_s, tz=timezone.utc)


def horizontal_std_m(cov_enu: np.ndarray) -> float:
    """RMS of the east and north 1-sigma: the vertical one is ~100 m for signs without altitude."""
    return float(np.sqrt((cov_enu[0, 0] + cov_enu[1, 1]) / 2.0))


def map_sign_values(sign: MapSign) -> dict[str, Any]:
    """The columns of a map sign row (all but id and the created/updated/removed stamps)."""
    cov = np.asarray(sign.cov_enu, dtype=float)
    return {"cls": sign.cls, "lat_deg": float(sign.lat_deg), "lon_deg": float(sign.lon_deg),
            "alt_m": None if sign.alt_m is None else float(sign.alt_m),
            "cov_enu": cov.tolist(), "std_m": horizontal_std_m(cov), "facing_deg": sign.facing_deg,
            "n_journeys": len(sign.journeys), "n_observations": int(sign.n_observations),
            "first_seen_at": _utc(sign.first_seen_at), "last_seen_at": _utc(sign.last_seen_at),
            "state": sign.state, "evidence": sign.evidence}


def _close(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
    return a == b


def differs(row: MapSignRow, values: dict[str, Any]) -> bool:
    """A change a map client should hear about: not the last-bit noise a shifted fusion frame
    (another journey's signs in the region) puts into unchanged signs (1e-9 deg is 0.1 mm)."""
    return not all(_close(getattr(row, key), value) for key, value in values.items())

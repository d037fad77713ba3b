"""Helpers of the service tests: pipeline results as a worker would store them, and comparisons of
GeoJSON signs with a synthetic journey's truth."""

from __future__ import annotations

import secrets

import numpy as np

from app.service.db.session import session_scope
from tests.utils import bundle_factory as bf


def made_result(signs: list[tuple[str, str, float, float, float | None]], source: str = "self",
                fx: float = 50.0, window=None):
    """A JourneyResult as the pipeline would return it, with signs (track, class, lat, lon, alt)
    seen in frames 000000 and 000001 of the factory bundle; ``window``: the calibration's turn
    window (``types.WindowObservations``), None: not kept."""
    from app.pipeline.types import (Calibration, CameraModel, JourneyResult, Sign,
                                    SignObservation)

    camera = CameraModel(64, 48, fx, fx + 1.0, 31.5, 23.5, -0.1, 0.01)
    return JourneyResult(
        calibration=Calibration(camera, source, n_images=5, n_registered=5,
                                reprojection_error_px=0.4, rotation_deg=35.0,
                                observations=window),
        signs=[Sign(track, cls, np.array([float(i), 2.0, 1.5]), lat, lon, alt, 0.2, 0.7,
                    [SignObservation("000000", (1.0 + i, -0.5, 12.0)),
                     SignObservation("000001", (0.8 + i, -0.5, 11.0))],
                    facing_deg=(90.0 * i) % 360.0, r95_h_m=0.5 + 0.1 * i)
               for i, (track, cls, lat, lon, alt) in enumerate(signs)],
        rejected=[], timings_s={"turns": 0.01, "calibrate": 1.5})


def finish(stack, journey_id: str, result, files: dict | None = None) -> int:
    """Do what a worker does with ``result``: claim the journey and store it; returns the attempt."""
    from app.pipeline.bundle import read_bundle
    from app.service.jobs import state

    work = stack.settings.data_dir / "test-extract" / secrets.token_hex(4)
    (work / "b.zip").parent.mkdir(parents=True)
    (work / "b.zip").write_bytes(bf_zip(files))
    journey = read_bundle(work / "b.zip", work / "x", decode_images=False)
    with session_scope(stack.url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    assert attempt is not None
    with session_scope(stack.url) as session:
        assert state.store_result(session, journey_id, attempt, journey, result,
                                     {"total_s": 2.0})
    return attempt


def bf_zip(files: dict | None = None) -> bytes:
    return bf.zip_bytes(files if files is not None else bf.valid_files())


def signs_enu(features: list[dict], truth: dict) -> dict[str, np.ndarray]:
    """Each feature's position (m) in the truth's ENU frame, keyed by track id."""
    from app.pipeline.geometry.geodesy import frame_at

    origin = truth["origin"]
    frame = frame_at(origin["lat"], origin["lon"], origin["alt_m"])
    positions = {}
    for feature in features:
        lon, lat, alt = feature["geometry"]["coordinates"]
        positions[feature["properties"]["track_id"]] = frame.to_local([lat], [lon], [alt])[0]
    return positions


def sign_errors_m(features: list[dict], truth: dict) -> dict[str, float]:
    """Distance (m) from each feature to the true sign of its track."""
    true = signs_enu([{"properties": {"track_id": str(s["track_id"])},
                       "geometry": {"coordinates": [s["lon"], s["lat"], s["alt_m"]]}}
                      for s in truth["signs"]], truth)
    return {track: float(np.linalg.norm(xyz - true[track]))
            for track, xyz in signs_enu(features, truth).items()}


def nearest_sign_errors_m(features: list[dict], truth: dict) -> dict[str, float]:
    """Distance (m) from each feature to the nearest true sign of its class, keyed by its track id:
    for tracks the pipeline made itself (``auto-N``), which name no true sign."""
    true = signs_enu([{"properties": {"track_id": str(s["track_id"])},
                       "geometry": {"coordinates": [s["lon"], s["lat"], s["alt_m"]]}}
                      for s in truth["signs"]], truth)
    cls = {str(s["track_id"]): s["class"] for s in truth["signs"]}
    by_track = {f["properties"]["track_id"]: f["properties"]["class"] for f in features}
    return {track: min((float(np.linalg.norm(xyz - true[t])) for t in true
                        if cls[t] == by_track[track]), default=float("inf"))
            for track, xyz in signs_enu(features, truth).items()}


def truth_bbox(truth: dict, margin_deg: float = 1e-3) -> str:
    lats = [s["lat"] for s in truth["signs"]]
    lons = [s["lon"] for s in truth["signs"]]
    return ",".join(f"{v:.7f}" for v in (min(lons) - margin_deg, min(lats) - margin_deg,
                                         max(lons) + margin_deg, max(lats) + margin_deg))

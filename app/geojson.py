"""GeoJSON (RFC 7946) of signs, as the wire contract fixes it. Shared by the CLI and the API."""

from __future__ import annotations

from typing import Any, Iterable


def sign_feature(sign_id: str, cls: str, lon_deg: float, lat_deg: float, alt_m: float | None,
                 **properties: Any) -> dict[str, Any]:
    """A Point feature ``[lon, lat, alt_m]`` (alt omitted when unknown) with ``id`` and ``class``."""
    coords = [lon_deg, lat_deg] if alt_m is None else [lon_deg, lat_deg, alt_m]
    props = {"id": sign_id, "class": cls, **properties}
    return {"type": "Feature", "id": sign_id, "geometry": {"type": "Point", "coordinates": coords},
            "properties": props}


def feature_collection(features: Iterable[dict[str, Any]], **members: Any) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features), **members}


def journey_sign_features(signs, id_prefix: str = "") -> list[dict[str, Any]]:
    """Features of a pipeline result's signs (``app.pipeline.types.Sign``), with observations."""
    return [
        sign_feature(
            f"{id_prefix}{s.track_id}", s.cls, float(s.lon_deg), float(s.lat_deg),
            None if s.alt_m is None else float(s.alt_m),
            track_id=s.track_id, std_m=float(s.std_m), facing_deg=s.facing_deg,
            reprojection_rms_px=float(s.reprojection_rms_px),
            observations=[{"frame": o.frame_id, "x": o.p_cam[0], "y": o.p_cam[1], "z": o.p_cam[2]}
                          for o in s.observations],
        )
        for s in signs
    ]

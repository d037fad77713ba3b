"""Change detection: which map signs appeared or disappeared, from where journeys looked.

A map sign is IN VIEW of a frame when it lies ``view_min_depth_m``..``view_max_depth_m`` (4..35 m)
in front of the camera and its projection through the journey's lens (OpenCV, radial k1, k2) lands
at least ``view_margin_px`` (10 px) inside the image. Occlusion is not modelled. A journey PASSES a
sign when it had the sign in view in >= ``min_frames_in_view`` (3) frames or detected it; it
DETECTED it when one of its signs is a member (or its journey_key is among the sign's journeys).
Passes are ordered by (captured_at, journey_key). Rules, first match wins:

* ``possibly_removed``: the K = ``removal_journeys`` (3) most recent passes all missed the sign and
  all came after its last detection (``last_seen_at``).
* ``new``: at least ``new_min_prior_misses`` (2) passes missed the sign before its first detection
  (``first_seen_at``): older journeys drove past with it in view and did not see it.
* ``confirmed``: otherwise (including signs no coverage says anything about).

The rule and the journeys behind it go to ``evidence["change"]``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from app.fusion.config import FusionConfig
from app.fusion.types import JourneyCoverage, MapSign
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import CameraModel


def _max_undistorted_radius(camera: CameraModel) -> float:
    """Normalised radius beyond which r (1 + k1 r^2 + k2 r^4) folds back (points there would
    wrongly project into the image); infinite when it never does."""
    # d/dr of the distortion is 1 + 3 k1 s + 5 k2 s^2 with s = r^2.
    roots = np.roots([5.0 * camera.k2, 3.0 * camera.k1, 1.0]) if camera.k2 else (
        np.array([-1.0 / (3.0 * camera.k1)]) if camera.k1 else np.array([]))
    s = [float(r.real) for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
    return math.sqrt(min(s)) if s else math.inf


def frames_in_view(xyz_world: np.ndarray, T_world_cam: np.ndarray, camera: CameraModel,
                   config: FusionConfig) -> np.ndarray:
    """For points ``xyz_world`` (M, 3), the number of poses (N, 4, 4) that have each in view."""
    xyz = np.asarray(xyz_world, dtype=float).reshape(-1, 3)
    counts = np.zeros(len(xyz), dtype=int)
    if len(xyz) == 0 or len(T_world_cam) == 0:
        return counts
    centres = T_world_cam[:, :3, 3]
    near = cKDTree(centres[:, :2]).query_ball_point(xyz[:, :2], r=config.view_max_depth_m)
    sign_idx = np.repeat(np.arange(len(xyz)), [len(n) for n in near])
    frame_idx = np.array([f for n in near for f in n], dtype=int)
    if len(frame_idx) == 0:
        return counts
    R_world_cam = T_world_cam[frame_idx, :3, :3]
    p_cam = np.einsum("nji,nj->ni", R_world_cam, xyz[sign_idx] - centres[frame_idx])
    z = p_cam[:, 2]
    ok = (z >= config.view_min_depth_m) & (z <= config.view_max_depth_m)
    radius = np.hypot(p_cam[:, 0], p_cam[:, 1]) / np.where(z > 0, z, 1.0)
    ok &= radius < _max_undistorted_radius(camera)
    if not ok.any():
        return counts
    uv, _ = cv2.projectPoints(p_cam[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K,
                              camera.dist)
    uv = uv.reshape(-1, 2)
    m = config.view_margin_px
    inside = ((uv[:, 0] >= m) & (uv[:, 0] <= camera.width - 1 - m)
              & (uv[:, 1] >= m) & (uv[:, 1] <= camera.height - 1 - m))
    return np.bincount(sign_idx[ok][inside], minlength=len(xyz))


@dataclass(frozen=True)
class _Pass:
    journey_key: str
    captured_at: float
    frames_in_view: int
    detected: bool

    def as_evidence(self) -> dict:
        return {"journey_key": self.journey_key, "captured_at": self.captured_at,
                "frames_in_view": self.frames_in_view}


def _sign_xyz(map_signs: list[MapSign], coverage: JourneyCoverage,
              config: FusionConfig) -> np.ndarray:
    """Map signs in the journey's ENU frame; a sign without altitude is put a fixed height above
    the nearest camera, as its height matters for the projection."""
    frame = frame_at(*coverage.origin_lat_lon_alt)
    alt = np.array([np.nan if s.alt_m is None else s.alt_m for s in map_signs], dtype=float)
    xyz = frame.to_local([s.lat_deg for s in map_signs], [s.lon_deg for s in map_signs], alt)
    no_alt = ~np.isfinite(alt)
    if no_alt.any() and len(coverage.T_world_cam):
        centres = coverage.T_world_cam[:, :3, 3]
        _, nearest = cKDTree(centres[:, :2]).query(xyz[no_alt, :2])
        xyz[no_alt, 2] = centres[nearest, 2] + config.sign_above_camera_m
    return xyz


def judge_window(sign: MapSign, passes: list[_Pass], config: FusionConfig) -> MapSign:
    recent = passes[-config.removal_journeys:] if config.removal_journeys > 0 else []
    prior = [p for p in passes if not p.detected and p.captured_at < sign.first_seen_at]
    if (len(recent) == config.removal_journeys and recent and not any(p.detected for p in recent)
            and recent[0].captured_at > sign.last_seen_at):
        state, change = "possibly_removed", {"missed_by": [p.as_evidence() for p in recent],
                                             "last_seen_at": sign.last_seen_at}
    elif len(prior) >= config.new_min_prior_misses:
        state, change = "new", {"missed_before_by": [p.as_evidence() for p in prior],
                                "first_seen_at": sign.first_seen_at}
    else:
        state, change = "confirmed", {}
    change.update(rule=state, n_passes=len(passes),
                  n_detected=sum(p.detected for p in passes))
    return dataclasses.replace(sign, state=state, evidence={**sign.evidence, "change": change})


def detect_changes(map_signs: list[MapSign], journeys: list[JourneyCoverage], *,
                   config: FusionConfig | None = None) -> list[MapSign]:
    """Copies of ``map_signs`` (same order) with ``state`` and ``evidence["change"]`` set."""
    config = config or FusionConfig()
    passes: list[list[_Pass]] = [[] for _ in map_signs]
    members = [set(s.members) for s in map_signs]
    for coverage in sorted(journeys, key=lambda c: (c.captured_at, c.journey_key)):
        T_world_cam = np.asarray(coverage.T_world_cam, dtype=float).reshape(-1, 4, 4)
        coverage = dataclasses.replace(coverage, T_world_cam=T_world_cam)
        counts = frames_in_view(_sign_xyz(map_signs, coverage, config), T_world_cam,
                                coverage.camera, config)
        detected_ids = set(coverage.detected_sign_ids)
        for n, sign in enumerate(map_signs):
            detected = bool(members[n] & detected_ids) or (
                coverage.journey_key in sign.journeys)
            if detected or counts[n] >= config.min_frames_in_view:
                passes[n].append(_Pass(coverage.journey_key, float(coverage.captured_at),
                                       int(counts[n]), detected))
    return [judge_window(sign, p, config) for sign, p in zip(map_signs, passes)]

"""Change detection: which frames see a map sign, and new / confirmed / possibly_removed."""

from __future__ import annotations

import hashlib

import cv2
import numpy as np

from app.fusion import (FusionConfig, JourneyCoverage, JourneySign, detect_changes,
                        frames_in_view, fuse_map)
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import CameraModel

ORIGIN = (49.0110123, 8.4183456, 112.3)
FRAME = frame_at(*ORIGIN)
T0 = 1_700_000_000.0
CAMERA = CameraModel(1242, 375, 720.0, 720.0, 620.5, 187.0, -0.3, 0.1)
# Camera looking east along the road: x right = south, y down, z forward = east.
R_WORLD_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
CAMERA_UP_M = 1.5


def poses_east(x_from_m: float, x_to_m: float, step_m: float = 1.0) -> np.ndarray:
    """(N, 4, 4) T_world_cam along y = 0 in FRAME, every ``step_m``."""
    xs = np.arange(x_from_m, x_to_m + 1e-9, step_m)
    T = np.repeat(np.eye(4)[None], len(xs), axis=0)
    T[:, :3, :3] = R_WORLD_CAM
    T[:, :3, 3] = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, CAMERA_UP_M)])
    return T


def test_frames_in_view_counts_the_depth_window_exactly():
    T = poses_east(-40.0, 150.0)
    config = FusionConfig()
    # Straight ahead at camera height: projects on the principal point whenever 4..35 m ahead,
    # i.e. from cameras at x = 5 .. 36: 32 frames. Behind every camera: none.
    ahead_and_behind = np.array([[40.0, 0.0, CAMERA_UP_M], [-60.0, 0.0, CAMERA_UP_M]])
    assert frames_in_view(ahead_and_behind, T, CAMERA, config).tolist() == [32, 0]
    narrow = FusionConfig(view_min_depth_m=10.0, view_max_depth_m=20.0)
    assert frames_in_view(ahead_and_behind, T, CAMERA, narrow).tolist() == [11, 0]


def test_points_beyond_the_lens_fold_are_not_in_view():
    """With k1 = -0.3 the distortion folds back beyond r = 1.05: a point at r = 1.9 lands inside
    the image under the polynomial, though the lens cannot see it."""
    camera = CAMERA.replace(k2=0.0)
    T = poses_east(0.0, 0.0)
    p_world = np.array([[10.0, -19.0, CAMERA_UP_M]])  # 10 m ahead, 19 m to the right
    p_cam = (R_WORLD_CAM.T @ (p_world[0] - T[0, :3, 3]))[None, None]
    uv, _ = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    assert 0 <= uv[0, 0, 0] < camera.width and 0 <= uv[0, 0, 1] < camera.height
    assert frames_in_view(p_world, T, camera, FusionConfig()).tolist() == [0]


# Real signs (FRAME ENU), the journeys that detect each, and the journeys' routes.
SIGNS = {
    "A": ([40.0, -4.0, 2.5], "stop", {0, 1, 2}),  # gone after journey 2
    "B": ([80.0, -4.0, 2.5], "yield", {4, 5}),  # put up before journey 4
    "C": ([120.0, -4.0, 2.5], "speed_50", {0, 1, 2, 3, 4, 5}),
    "D": ([160.0, -4.0, 2.5], "no_entry", {0, 1, 2, 3}),  # missed twice: not enough
    "E": ([40.0, 500.0, 2.5], "stop", {0}),  # on a road nobody else drove
    "G": ([200.0, -4.0, 2.5], "yield", {4, 5}),  # only the later journeys drove this far
}


def journey_key(j: int) -> str:
    return hashlib.sha256(f"change-{j}".encode()).hexdigest()


def _route(j: int) -> np.ndarray:
    return poses_east(-40.0, 150.0 if j < 4 else 220.0)


def _journeys():
    rng = np.random.default_rng(17)
    signs, coverage = [], []
    for j in range(6):
        mine = []
        for name, (xyz, cls, seen_by) in SIGNS.items():
            if j in seen_by:
                lat, lon, alt = FRAME.to_geodetic(np.array(xyz) + rng.normal(0.0, 0.1, 3))
                mine.append(JourneySign(f"j{j}:{name}", journey_key(j), cls, float(lat[0]),
                                        float(lon[0]), float(alt[0]), np.eye(3) * 0.01,
                                        T0 + 86400.0 * j))
        signs += mine
        # Each journey's ENU frame starts at its own first pose, as the pipeline's does.
        T_origin = _route(j)
        lat0, lon0, alt0 = (float(v[0]) for v in FRAME.to_geodetic(T_origin[0, :3, 3]))
        own = frame_at(lat0, lon0, alt0)
        T_own = T_origin.copy()
        T_own[:, :3, 3] = own.to_local(*FRAME.to_geodetic(T_origin[:, :3, 3]))
        coverage.append(JourneyCoverage(journey_key(j), T0 + 86400.0 * j, T_own,
                                        (lat0, lon0, alt0), CAMERA, {s.sign_id for s in mine}))
    return signs, coverage


def test_new_confirmed_and_possibly_removed():
    signs, coverage = _journeys()
    fused = fuse_map(signs).signs
    assert len(fused) == len(SIGNS)
    judged = detect_changes(fused, coverage[::-1])  # coverage order does not matter
    assert [m.map_id for m in judged] == [m.map_id for m in fused]
    state = {m.members[0].split(":")[1]: m for m in judged}
    assert {k: m.state for k, m in state.items()} == {
        "A": "possibly_removed", "B": "new", "C": "confirmed", "D": "confirmed",
        "E": "confirmed", "G": "confirmed"}

    removed = state["A"].evidence["change"]
    assert [e["journey_key"] for e in removed["missed_by"]] == [journey_key(j) for j in (3, 4, 5)]
    assert all(e["frames_in_view"] >= 3 for e in removed["missed_by"])
    assert removed["last_seen_at"] == T0 + 2 * 86400.0
    assert state["A"].evidence["weights"]  # fusion evidence is kept

    new = state["B"].evidence["change"]
    assert [e["journey_key"] for e in new["missed_before_by"]] == [journey_key(j) for j in range(4)]
    assert new["first_seen_at"] == T0 + 4 * 86400.0
    assert (state["C"].evidence["change"]["n_passes"], state["C"].evidence["change"]["n_detected"]) \
        == (6, 6)
    assert state["E"].evidence["change"]["n_passes"] == 1
    assert state["G"].evidence["change"]["n_passes"] == 2  # journeys 0-3 stopped short of it


def test_thresholds_move_the_verdicts():
    signs, coverage = _journeys()
    fused = fuse_map(signs).signs
    strict = FusionConfig(removal_journeys=2, new_min_prior_misses=5)
    state = {m.members[0].split(":")[1]: m.state
             for m in detect_changes(fused, coverage, config=strict)}
    # Two misses now suffice for D; four prior misses no longer make B new.
    assert (state["A"], state["B"], state["D"]) == ("possibly_removed", "confirmed",
                                                    "possibly_removed")
    # With only the three journeys before the removal, nothing is missing yet.
    early = {m.members[0].split(":")[1]: m.state
             for m in detect_changes(fused, coverage[:4])}
    assert early["A"] == "confirmed"
    assert detect_changes([], coverage) == []


def test_signs_without_altitude_are_placed_above_the_camera():
    signs, coverage = _journeys()
    no_alt = [JourneySign(s.sign_id, s.journey_key, s.cls, s.lat_deg, s.lon_deg, None, s.cov_enu,
                          s.captured_at) for s in signs]
    fused = fuse_map(no_alt).signs
    assert all(m.alt_m is None for m in fused)
    state = {m.members[0].split(":")[1]: m.state for m in detect_changes(fused, coverage)}
    assert (state["A"], state["B"], state["C"]) == ("possibly_removed", "new", "confirmed")

import cv2
import numpy as np
import pytest

from app.pipeline.geometry.triangulation import (ReprojectionError, TriangulatedPoint,
                                                 TriangulationError, midpoint, triangulate,
                                                 triangulate_inliers, undistort_pixels)
from app.pipeline.types import CameraModel

KITTI = CameraModel(width=1242, height=375, fx=959.0, fy=959.0, cx=696.0, cy=224.2,
                    k1=-0.369, k2=0.158)
K = KITTI.K


def _car_poses(heading_rad: float, along_m: np.ndarray) -> np.ndarray:
    """(M,4,4) T_world_cam of a level camera 1.5 m up, driving along ``heading`` through the ENU
    origin, at the given distances along the road."""
    z = np.array([np.cos(heading_rad), np.sin(heading_rad), 0.0])
    x = np.cross(z, [0.0, 0.0, 1.0])
    y = np.cross(z, x)
    T = np.tile(np.eye(4), (len(along_m), 1, 1))
    T[:, :3, :3] = np.column_stack([x, y, z])
    T[:, :3, 3] = along_m[:, None] * z + [0.0, 0.0, 1.5]
    return T


def _project(T_world_cam: np.ndarray, xyz_world: np.ndarray) -> np.ndarray:
    p_cam = np.einsum("mji,mj->mi", T_world_cam[:, :3, :3], xyz_world - T_world_cam[:, :3, 3])
    uvw = p_cam @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def _roadside_sign(rng: np.random.Generator):
    """A car approaching a sign on the right of the road; returns poses, the sign, its pixels."""
    heading = rng.uniform(-np.pi, np.pi)
    ahead_m = rng.uniform(25.0, 45.0)
    z = np.array([np.cos(heading), np.sin(heading), 0.0])
    right = np.cross(z, [0.0, 0.0, 1.0])
    sign = ahead_m * z + rng.uniform(3.0, 7.0) * right + [0.0, 0.0, rng.uniform(2.0, 3.5)]
    # Frames every ~1 m while the sign is in view and at least 8 m ahead.
    T = _car_poses(heading, np.arange(0.0, ahead_m - 8.0, rng.uniform(0.8, 1.5)))
    px = _project(T, sign)
    seen = np.all((px >= 0) & (px <= [KITTI.width - 1, KITTI.height - 1]), axis=1)
    return T[seen], sign, px[seen]


@pytest.mark.parametrize("seed", range(5))
def test_noise_free_recovers_the_sign(seed):
    T, sign, px = _roadside_sign(np.random.default_rng(seed))
    assert len(px) >= 10
    point = triangulate(T, px, K)
    assert isinstance(point, TriangulatedPoint)
    np.testing.assert_allclose(point.xyz_world, sign, atol=1e-6)
    assert point.rms_px < 1e-6
    expected_cam = np.einsum("mji,mj->mi", T[:, :3, :3], sign - T[:, :3, 3])
    np.testing.assert_allclose(point.p_cam, expected_cam, atol=1e-6)
    assert np.all(point.p_cam[:, 2] > 8.0)
    assert point.cov_world.shape == (3, 3)
    assert point.std_m == pytest.approx(np.sqrt(np.linalg.eigvalsh(point.cov_world)[-1]))


def test_half_pixel_noise_error_matches_covariance():
    rng = np.random.default_rng(42)
    ratios, mahalanobis = [], []
    for _ in range(60):
        T, sign, px = _roadside_sign(rng)
        point = triangulate(T, px + rng.normal(scale=0.5, size=px.shape), K, pixel_sigma=0.5)
        err = point.xyz_world - sign
        ratios.append(np.linalg.norm(err) / point.std_m)
        mahalanobis.append(err @ np.linalg.solve(point.cov_world, err))
        assert 0.3 < point.rms_px < 1.2
        assert point.std_m < 0.5
    ratios = np.asarray(ratios)
    assert np.mean(ratios <= 3.0) >= 0.95 and ratios.max() < 4.0
    # A calibrated 3-D covariance gives a mean squared Mahalanobis distance of 3.
    assert 1.8 < np.mean(mahalanobis) < 4.0


def test_behind_the_cameras_is_rejected():
    # Two forward-looking cameras whose rays diverge: the lines meet 10 m behind them.
    T = _car_poses(0.0, np.array([0.0, 0.0]))
    T[1, :3, 3] += [0.0, -2.0, 0.0]  # second camera 2 m to the right
    behind = np.array([-10.0, -1.0, 1.5])
    rays_to_mirror = 2 * T[:, :3, 3] - behind  # the mirrored point is in front of both
    px = np.array([_project(T[i:i + 1], rays_to_mirror[i])[0] for i in range(2)])
    with pytest.raises(TriangulationError, match=r"^behind camera in frame 0$"):
        triangulate(T, px, K)


def test_sign_already_passed_by_the_last_frame_is_rejected():
    rng = np.random.default_rng(7)
    T, sign, _ = _roadside_sign(rng)
    ahead_m = float(np.dot(sign[:2], T[0, :3, 2][:2]))
    T = _car_poses(np.arctan2(T[0, 1, 2], T[0, 0, 2]), np.array([0.0, 5.0, 10.0, ahead_m + 3.0]))
    # The last camera has driven past: its pixel is the one a pinhole gives for a point behind.
    with pytest.raises(TriangulationError, match=r"^behind camera in frame 3$"):
        triangulate(T, _project(T, sign), K)


def test_nearly_parallel_rays_are_rejected():
    T = _car_poses(0.3, np.array([0.0, 0.0]))
    T[1, :3, 3] += 0.1 * T[1, :3, 0]  # 10 cm to the side
    far = T[0, :3, 3] + 100.0 * T[0, :3, 2]
    with pytest.raises(TriangulationError, match=r"^rays nearly parallel \(0\.1 deg\)$"):
        triangulate(T, _project(T, far), K)
    # Lowering the threshold lets the same geometry through (with a large uncertainty).
    point = triangulate(T, _project(T, far), K, min_ray_angle_deg=0.01)
    np.testing.assert_allclose(point.xyz_world, far, atol=1e-4)
    assert point.std_m > 10.0


def test_bad_reprojection_and_divergence_are_rejected():
    T, sign, px = _roadside_sign(np.random.default_rng(3))
    bad = px.copy()
    bad[::2] += [25.0, -15.0]  # half the detections are off by 29 px
    with pytest.raises(TriangulationError, match=r"^reprojection rms \d+\.\d px > 4\.0$"):
        triangulate(T, bad, K)
    noisy = px + np.random.default_rng(4).normal(scale=1.0, size=px.shape)
    with pytest.raises(TriangulationError, match=r"^refinement diverged \(moved"):
        triangulate(T, noisy, K, max_shift_sigma=1e-6)
    with pytest.raises(TriangulationError, match="at least 2"):
        triangulate(T[:1], px[:1], K)


def test_one_outlier_is_downweighted_by_the_robust_loss():
    T, sign, px = _roadside_sign(np.random.default_rng(5))
    px = px + np.random.default_rng(6).normal(scale=0.3, size=px.shape)
    px[len(px) // 2] += [12.0, 0.0]
    robust = triangulate(T, px, K, max_rms_px=10.0)
    plain = triangulate(T, px, K, loss="linear", max_rms_px=10.0)
    assert np.linalg.norm(robust.xyz_world - sign) < np.linalg.norm(plain.xyz_world - sign)
    assert np.linalg.norm(robust.xyz_world - sign) < 0.1


def test_midpoint_of_skew_rays():
    centres = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    dirs = np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(midpoint(centres, dirs), [0.0, 0.0, 0.0], atol=1e-12)
    target = np.array([3.0, -2.0, 7.0])
    centres = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(midpoint(centres, target - centres), target, atol=1e-12)


def test_undistort_pixels_round_trips_kitti_lens_to_the_corners():
    u, v = np.meshgrid(np.linspace(0, KITTI.width - 1, 32), np.linspace(0, KITTI.height - 1, 12))
    px = np.column_stack([u.ravel(), v.ravel()])
    assert {(0.0, 0.0), (1241.0, 374.0), (0.0, 374.0), (1241.0, 0.0)} <= set(map(tuple, px))
    px_rect = undistort_pixels(KITTI, px)
    # The corners of a barrel lens move outwards by tens of pixels when undistorted.
    assert np.linalg.norm(px_rect[0] - px[0]) > 20.0
    rays = np.column_stack([(px_rect - [KITTI.cx, KITTI.cy]) / [KITTI.fx, KITTI.fy],
                            np.ones(len(px))])
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, KITTI.dist)
    assert np.abs(back.reshape(-1, 2) - px).max() < 1e-3
    assert undistort_pixels(KITTI, np.zeros((0, 2))).shape == (0, 2)
    no_lens = KITTI.replace(k1=0.0, k2=0.0)
    np.testing.assert_allclose(undistort_pixels(no_lens, px), px, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_a_few_boxes_on_the_wrong_object_are_dropped_and_the_rest_place_the_sign(seed):
    rng = np.random.default_rng(seed)
    T, sign, px = _roadside_sign(rng)
    px = px + rng.normal(0.0, 0.5, px.shape)
    wrong = rng.choice(len(px), size=max(1, len(px) // 6), replace=False)
    px[wrong] += rng.choice([-1, 1], size=(len(wrong), 2)) * rng.uniform(25, 40, (len(wrong), 2))
    with pytest.raises(ReprojectionError) as exc:
        triangulate(T, px, K)
    assert exc.value.residuals_px.shape == (len(px),) and exc.value.residuals_px.max() > 4.0
    point, used = triangulate_inliers(T, px, K, min_inlier_share=0.7, min_inliers=3)
    assert set(np.flatnonzero(~used)) == set(wrong.tolist())
    assert np.linalg.norm(point.xyz_world - sign) < 0.3
    assert point.p_cam.shape == (used.sum(), 3)
    # Asked for more inliers than there are, the track stays rejected for its reprojection.
    with pytest.raises(ReprojectionError):
        triangulate_inliers(T, px, K, min_inlier_share=0.95, min_inliers=3)


def test_a_track_that_fits_no_single_point_stays_rejected():
    rng = np.random.default_rng(7)
    T, sign, px = _roadside_sign(rng)
    px = px + rng.normal(0.0, 12.0, px.shape)  # boxes scattered all over: a false track
    with pytest.raises(TriangulationError):
        triangulate_inliers(T, px, K, min_inlier_share=0.7, min_inliers=3)

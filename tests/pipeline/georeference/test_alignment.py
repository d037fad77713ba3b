import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import Sim3, align_trajectory, umeyama


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(R_a @ R_b.T).magnitude()))


def _random_sim(seed: int) -> Sim3:
    rng = np.random.default_rng(seed)
    return Sim3(float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(),
                rng.uniform(-100, 100, 3))


def _level_cameras(xyz_world: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
    """(N,3,3) R_world_cam of level cameras looking along the track, yawed by yaw_deg (left)."""
    d = np.gradient(xyz_world, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0]) + np.radians(yaw_deg)
    z = np.column_stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)])
    x = np.cross(z, [0.0, 0.0, 1.0])
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def test_sim3_apply_inverse_and_poses():
    sim = _random_sim(3)
    p = np.random.default_rng(1).normal(size=(7, 3))
    np.testing.assert_allclose(sim.inverse().apply(sim.apply(p)), p, atol=1e-12)
    np.testing.assert_allclose(sim.apply(p[0]), sim.scale * sim.R @ p[0] + sim.t, atol=1e-12)
    T_model_cam = np.tile(np.eye(4), (2, 1, 1))
    T_model_cam[:, :3, :3] = Rotation.random(2, random_state=4).as_matrix()
    T_model_cam[:, :3, 3] = p[:2]
    T_world_cam = sim.apply_poses(T_model_cam)
    np.testing.assert_allclose(T_world_cam[:, :3, :3], sim.R @ T_model_cam[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(T_world_cam[:, :3, 3], sim.apply(p[:2]), atol=1e-12)
    np.testing.assert_allclose(T_world_cam[:, 3], [[0, 0, 0, 1]] * 2)
    # A point seen in the camera maps to the same world point either way.
    p_cam = np.array([0.3, -0.2, 4.0])
    via_model = sim.apply(T_model_cam[0, :3, :3] @ p_cam + T_model_cam[0, :3, 3])
    np.testing.assert_allclose(T_world_cam[0, :3, :3] @ (sim.scale * p_cam) + T_world_cam[0, :3, 3],
                               via_model, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_umeyama_recovers_known_similarity_exactly(seed):
    true = _random_sim(seed)
    src = np.random.default_rng(seed + 10).normal(scale=20.0, size=(25, 3))
    est = umeyama(src, true.apply(src))
    assert est.scale == pytest.approx(true.scale, abs=1e-9)
    np.testing.assert_allclose(est.R, true.R, atol=1e-9)
    np.testing.assert_allclose(est.t, true.t, atol=1e-9)


def test_umeyama_rigid_and_noisy():
    true = Sim3(1.0, Rotation.random(random_state=7).as_matrix(), np.array([3.0, -4.0, 5.0]))
    rng = np.random.default_rng(7)
    src = rng.normal(scale=30.0, size=(200, 3))
    rigid = umeyama(src, true.apply(src), with_scale=False)
    np.testing.assert_allclose(rigid.R, true.R, atol=1e-9)
    np.testing.assert_allclose(rigid.t, true.t, atol=1e-9)
    assert rigid.scale == 1.0

    # 0.5 m noise on 200 points spread over ~30 m: rotation within a few 0.5/(30*sqrt(200)) rad.
    noisy = umeyama(src, true.apply(src) + rng.normal(scale=0.5, size=src.shape))
    assert abs(noisy.scale - 1.0) < 0.01
    assert _angle_deg(noisy.R, true.R) < 0.1
    assert np.linalg.norm(noisy.t - true.t) < 0.3


def test_umeyama_robust_ignores_gps_outliers():
    true = _random_sim(5)
    rng = np.random.default_rng(5)
    src = rng.normal(scale=10.0, size=(60, 3))
    dst = true.apply(src) + rng.normal(scale=0.05, size=src.shape)
    dst[::10] += rng.normal(scale=30.0, size=(6, 3))
    assert _angle_deg(umeyama(src, dst).R, true.R) > 1.0
    robust = umeyama(src, dst, robust_max_error_m=0.5)
    assert _angle_deg(robust.R, true.R) < 0.2
    assert robust.scale == pytest.approx(true.scale, rel=5e-3)


def test_umeyama_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    with pytest.raises(ValueError, match="degenerate"):
        umeyama(line, 2 * line)


def _straight_journey(seed: int, yaw_deg: float, gps_noise_m: float):
    """Model-frame data of a car driving 60 m along a straight, slightly climbing road."""
    rng = np.random.default_rng(seed)
    true = _random_sim(seed)
    s = np.arange(0.0, 60.0, 1.0)
    heading = np.radians(35.0)
    xyz_world = np.column_stack([s * np.cos(heading), s * np.sin(heading), 0.03 * s])
    R_world_cam = _level_cameras(xyz_world, yaw_deg)
    inv = true.inverse()
    # Visual odometry is never exactly straight: centimetre wiggles in the model.
    centres_model = inv.apply(xyz_world + rng.normal(scale=0.02, size=xyz_world.shape))
    R_model_cam = true.R.T @ R_world_cam
    xyz_gps = xyz_world + rng.normal(scale=gps_noise_m, size=xyz_world.shape)
    return true, centres_model, xyz_gps, R_model_cam


def test_straight_road_plain_umeyama_rolls_but_gravity_fixes_it():
    true, centres_model, xyz_gps, R_model_cam = _straight_journey(0, yaw_deg=4.0, gps_noise_m=0.1)
    plain = umeyama(centres_model, xyz_gps)
    assert _angle_deg(plain.R, true.R) > 10.0  # the roll about the road is noise-driven

    sim, info = align_trajectory(centres_model, xyz_gps, R_model_cam)
    assert info["degenerate"] is True and info["roll_from"] == "gravity"
    assert info["n"] == 60
    assert _angle_deg(sim.R, true.R) < 0.5
    assert sim.scale == pytest.approx(true.scale, rel=0.01)
    assert info["scale"] == sim.scale
    assert info["rms_m"] < 0.3


def test_straight_road_roll_from_fallback():
    true, centres_model, xyz_gps, R_model_cam = _straight_journey(1, yaw_deg=0.0, gps_noise_m=0.1)
    assert _angle_deg(umeyama(centres_model, xyz_gps).R, true.R) > 10.0
    # A fallback from a longer alignment, itself 0.2 deg off, and cameras that are NOT level (so
    # gravity would mislead): the fallback's roll must win.
    error = Rotation.from_rotvec(np.radians(0.2) * np.array([0.6, 0.0, 0.8])).as_matrix()
    R_fallback = error @ true.R
    tilted = Rotation.from_rotvec([0.0, 0.0, np.radians(8.0)]).as_matrix()  # 8 deg camera roll
    sim, info = align_trajectory(centres_model, xyz_gps, R_model_cam @ tilted,
                                 R_fallback=R_fallback)
    assert info["degenerate"] is True and info["roll_from"] == "fallback"
    assert _angle_deg(sim.R, true.R) < 0.5
    gravity, _ = align_trajectory(centres_model, xyz_gps, R_model_cam @ tilted)
    assert _angle_deg(gravity.R, true.R) > 5.0


def test_curved_track_recovers_exactly():
    true = _random_sim(11)
    theta = np.linspace(0.0, np.pi / 2, 50)
    xyz_world = np.column_stack([30 * np.sin(theta), 30 - 30 * np.cos(theta), 0.02 * theta])
    R_model_cam = true.R.T @ _level_cameras(xyz_world)
    centres_model = true.inverse().apply(xyz_world)
    sim, info = align_trajectory(centres_model, xyz_world, R_model_cam)
    assert info["degenerate"] is False and info["roll_from"] == "positions"
    assert info["rms_m"] < 1e-9
    np.testing.assert_allclose(sim.R, true.R, atol=1e-9)
    assert sim.scale == pytest.approx(true.scale, abs=1e-9)
    np.testing.assert_allclose(sim.t, true.t, atol=1e-8)


def test_standing_still_is_refused():
    with pytest.raises(ValueError, match="do not move"):
        align_trajectory(np.random.default_rng(0).normal(size=(5, 3)), np.ones((5, 3)),
                         np.tile(np.eye(3), (5, 1, 1)))


def test_umeyama_agrees_with_pycolmap_on_rigid_motion():
    src = np.random.default_rng(2).normal(scale=5.0, size=(12, 3))
    R = Rotation.random(random_state=2).as_matrix()
    dst = src @ R.T + 1.5
    ref = pycolmap.estimate_sim3d(src, dst)
    est = umeyama(src, dst, with_scale=False)
    np.testing.assert_allclose(est.R, ref.rotation.matrix(), atol=1e-9)


def test_a_partial_similarity_goes_part_of_the_way_about_its_pivot():
    sim = Sim3(1.1, Rotation.from_rotvec([0.0, 0.0, 0.2]).as_matrix(), np.array([3.0, -1.0, 0.5]))
    pivot = np.array([10.0, 5.0, 1.0])
    none, half, whole = (sim.partial(w, pivot) for w in (0.0, 0.5, 1.0))
    np.testing.assert_allclose(none.apply(np.eye(3)), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(whole.apply(np.eye(3)), sim.apply(np.eye(3)), atol=1e-12)
    assert half.scale == pytest.approx(np.sqrt(1.1))
    assert Rotation.from_matrix(half.R).magnitude() == pytest.approx(0.1)
    np.testing.assert_allclose(half.apply(pivot), (pivot + sim.apply(pivot)) / 2, atol=1e-12)

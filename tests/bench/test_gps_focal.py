"""The GPS check of the focal length: a trajectory whose rotations are all too large by a factor
(what a short focal length does to ego-motion) is recognised by that factor."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.steps.ego_motion import WindowPoses
from bench.gps_focal import focal_evidence, unbent_centres


def _turn(n: int, turn_deg: float, radius_m: float, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """(T_model_cam (n, 4, 4), xyz (n, 3)): a car driving 20 m straight, then a circular turn of
    ``turn_deg``, then 20 m straight; the reconstruction sees every heading change ``kappa``
    times too large and is expressed in a rotated, scaled model frame."""
    arc_m = np.radians(turn_deg) * radius_m
    s_m = np.linspace(0.0, 40.0 + arc_m, n)
    heading = np.radians(turn_deg) * np.clip((s_m - 20.0) / arc_m, 0.0, 1.0)
    ds = np.diff(s_m)

    def chain(h: np.ndarray) -> np.ndarray:
        steps = np.stack([np.cos(h[:-1]), np.sin(h[:-1]), np.zeros(n - 1)], axis=1) * ds[:, None]
        return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])

    xyz = chain(heading)
    xyz_seen = chain(kappa * heading)
    # Camera looking along the heading: z forward, x right, y down; ENU x east, z up.
    R_enu_cam = np.stack([
        Rotation.from_euler("z", kappa * h).as_matrix()
        @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        for h in heading])
    R_model_enu = Rotation.from_euler("xyz", [20, -35, 110], degrees=True).as_matrix()
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R_model_enu @ R_enu_cam
    T[:, :3, 3] = 0.37 * xyz_seen @ R_model_enu.T + np.array([3.0, -1.0, 2.0])
    return T, xyz


def test_unbending_by_the_true_factor_restores_the_shape():
    T, xyz = _turn(60, 90.0, 15.0, 1.04)
    c = unbent_centres(T, 1.04)
    d_true = np.linalg.norm(xyz[:, None] - xyz[None], axis=2)
    d_unbent = np.linalg.norm(c[:, None] - c[None], axis=2) / 0.37
    np.testing.assert_allclose(d_unbent, d_true, atol=1e-6)


@pytest.mark.parametrize("kappa", [0.97, 1.0, 1.03])
def test_the_rotation_scale_is_found_under_gps_noise(kappa):
    rng = np.random.default_rng(5)
    windows, xyz_all = [], []
    for k, (turn_deg, radius_m) in enumerate([(90.0, 15.0), (60.0, 30.0)]):
        T, xyz = _turn(60, turn_deg, radius_m, kappa)
        windows.append(WindowPoses((60 * k, 60 * k + 60), np.arange(60 * k, 60 * k + 60), T))
        xyz_all.append(xyz + rng.normal(0.0, 0.2, xyz.shape))
    ev = focal_evidence(windows, np.vstack(xyz_all))
    assert ev is not None and ev.n_windows == 2
    assert ev.kappa == pytest.approx(kappa, abs=0.008)
    assert 0 < ev.kappa_std < 0.01
    assert ev.rms_best_m <= ev.rms_m


def test_straight_windows_are_no_evidence():
    T, xyz = _turn(40, 10.0, 50.0, 1.05)
    assert focal_evidence([WindowPoses((0, 40), np.arange(40), T)], xyz) is None


def test_gps_heading_follows_a_turn():
    from app.pipeline.config import PipelineConfig
    from bench.gps_focal import gps_heading_deg

    _, xyz = _turn(120, 90.0, 15.0, 1.0)
    heading = gps_heading_deg(xyz, np.arange(120) * 0.1, PipelineConfig())
    assert abs(heading[-1] - heading[0]) == pytest.approx(90.0, abs=3.0)

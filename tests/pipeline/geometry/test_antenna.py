"""The GPS antenna offset estimated from reconstructed windows (``geometry.antenna``): a straight
road into a turn tells it, a straight road alone does not, and correlated GPS errors widen its
sigma instead of hiding in it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from app.pipeline.geometry import gps_track
from app.pipeline.geometry.antenna import correlation_time, estimate_offset
from app.pipeline.types import AntennaEstimate

FORWARD_M, LEFT_M = -1.09, 0.25  # KITTI's GPS/INS unit, horizontally


def _drive(turn_deg: float, n: int = 200, speed_mps: float = 8.0, fps: float = 10.0,
           radius_m: float = 15.0, straight_m: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """(t_s (n,), camera centres (n, 3) ENU): a straight road, a left turn, a straight road."""
    s_m = np.arange(n) * speed_mps / fps
    arc_m = np.radians(turn_deg) * radius_m
    xy = np.zeros((n, 2))
    for i, s in enumerate(s_m):
        a = np.clip((s - straight_m) / radius_m, 0.0, np.radians(turn_deg))
        on_arc = np.array([straight_m + radius_m * np.sin(a), radius_m * (1.0 - np.cos(a))])
        past = max(s - straight_m - arc_m, 0.0)
        xy[i] = ([s, 0.0] if s < straight_m
                 else on_arc + past * np.array([np.cos(a), np.sin(a)]))
    return np.arange(n) / fps, np.column_stack([xy, np.full(n, 1.5)])


def _antenna(t_s: np.ndarray, camera: np.ndarray, rng, white_m: float = 0.1,
             wander_m: float = 0.0) -> np.ndarray:
    """The antenna's fixes at the frames: white noise and a horizontal bias that wanders over
    ~2 s (as the corpus's receivers' does)."""
    forward = gps_track.travel_direction(t_s, camera)
    left = np.column_stack([-forward[:, 1], forward[:, 0]])
    xyz = camera.copy()
    xyz[:, :2] += FORWARD_M * forward + LEFT_M * left
    xyz[:, 2] += 0.7
    xyz += rng.normal(0.0, white_m, xyz.shape)
    if wander_m:
        bias = gaussian_filter1d(rng.normal(size=(len(xyz), 2)), 20.0, axis=0)
        xyz[:, :2] += wander_m * bias / bias.std()
    return xyz


def _windows(t_s: np.ndarray, camera: np.ndarray, seed: int
             ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Two overlapping windows (their frames' times, their centres), each in its own model frame
    and scale."""
    out = []
    for k, (a, b) in enumerate(((0, 110), (100, len(camera)))):
        R = Rotation.random(random_state=seed + k).as_matrix()
        out.append((t_s[a:b], (camera[a:b] - camera[a]) @ R / 0.37))
    return out


def _estimate(t_s, camera, fixes, seed):
    """The estimate from the windows and every other frame's fix (a 5 Hz receiver)."""
    return estimate_offset(_windows(t_s, camera, seed), t_s[::2], fixes[::2])


def test_a_turn_tells_the_offset_within_its_sigma():
    rng = np.random.default_rng(0)
    errors, sigmas = [], []
    for trial in range(10):
        t_s, camera = _drive(90.0)
        est = _estimate(t_s, camera, _antenna(t_s, camera, rng), trial)
        assert est is not None and est.turn_deg > 80
        errors.append([est.forward_m - FORWARD_M, est.left_m - LEFT_M])
        sigmas.append([est.sigma_forward_m, est.sigma_left_m])
    errors, sigmas = np.abs(errors), np.array(sigmas)
    assert errors.max() < 0.25, errors
    assert np.median(sigmas) < 0.1
    assert np.mean(errors <= 2.5 * sigmas) >= 0.9, (errors, sigmas)


def test_a_straight_road_tells_nothing():
    rng = np.random.default_rng(1)
    t_s, camera = _drive(0.0)
    assert _estimate(t_s, camera, _antenna(t_s, camera, rng), 0) is None


def test_correlated_gps_errors_widen_the_sigma():
    """A receiver's bias that wanders: the residuals' correlation time widens the sigma."""
    t_s, camera = _drive(90.0)
    sigmas = {}
    for wander_m in (0.0, 0.15):
        sigmas[wander_m] = np.median([
            _estimate(t_s, camera, _antenna(t_s, camera, np.random.default_rng(trial),
                                            white_m=0.05, wander_m=wander_m), trial).sigma_m
            for trial in range(10)])
    assert sigmas[0.15] > 2.0 * sigmas[0.0], sigmas


@pytest.mark.parametrize("residual, expected", [
    (np.random.default_rng(0).normal(size=(400, 2)), (0.7, 1.5)),
    (np.repeat(np.random.default_rng(0).normal(size=(100, 2)), 4, axis=0), (4.0, 9.0)),
])
def test_correlation_time_counts_samples_that_repeat(residual, expected):
    assert expected[0] < correlation_time(residual) < expected[1]


def test_a_stop_before_the_turn_does_not_spoil_it():
    """Standing, the path points nowhere: those fixes are left out, not fitted."""
    t_s, camera = _drive(90.0)
    stand = 30  # 3 s standing at the start
    camera = np.concatenate([np.repeat(camera[:1], stand, axis=0), camera])
    t_s = np.arange(len(camera)) / 10.0
    fixes = _antenna(t_s, camera, np.random.default_rng(5))
    R = Rotation.random(random_state=5).as_matrix()
    est = estimate_offset([(t_s[:150], camera[:150] @ R)], t_s[::2], fixes[::2])
    assert est is not None
    assert abs(est.forward_m - FORWARD_M) < 0.3 and abs(est.left_m - LEFT_M) < 0.3, est


def test_journeys_estimates_combine_by_their_sigmas():
    sure = AntennaEstimate(-1.0, 0.2, 0.1, 0.4)
    unsure = AntennaEstimate(-2.0, 0.6, 0.3, 0.4, n_journeys=2)
    both = AntennaEstimate.combined([sure, unsure])
    # Forward: weights 100 and 11.1, so 90 % of the sure one; left: equal weights.
    assert both.forward_m == pytest.approx(-1.1) and both.left_m == pytest.approx(0.4)
    assert both.sigma_forward_m == pytest.approx((100 + 1 / 0.09) ** -0.5)
    assert both.sigma_left_m == pytest.approx(0.4 / np.sqrt(2)) and both.n_journeys == 3
    assert AntennaEstimate.combined([]) is None
    assert AntennaEstimate.from_json(both.to_json()) == both

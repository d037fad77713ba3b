"""Does one scale fit a reconstruction's camera path against GPS (``geometry.similarity.scale_spread``)?"""

import numpy as np
import pytest

from app.pipeline.geometry.similarity import scale_spread


def _turn_m(n: int = 22) -> np.ndarray:
    """Camera centres (m) along a 36 m road turning 90 deg, in travel order."""
    s_m = np.linspace(0.0, 36.0, n)
    heading = np.radians(np.clip((s_m - 10.0) * 90.0 / 16.0, 0.0, 90.0))
    step = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(n)])
    return np.vstack([[0.0, 0.0, 0.0], np.cumsum(step[1:] * np.diff(s_m)[:, None], axis=0)])


def test_a_reconstruction_of_one_scale_fits_it_whatever_its_frame():
    xyz_gps_m = _turn_m()
    rot = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    c_model = 0.17 * xyz_gps_m @ rot.T + [3.0, -1.0, 2.0]
    assert scale_spread(c_model, xyz_gps_m) == pytest.approx(1.0)
    # GPS noise of 1 m leaves it near 1.
    noisy = xyz_gps_m + np.random.default_rng(0).normal(0.0, 1.0, xyz_gps_m.shape) * [1, 1, 0]
    assert scale_spread(c_model, noisy) < 1.6


def test_a_partly_collapsed_reconstruction_does_not():
    xyz_gps_m = _turn_m()
    c_model = xyz_gps_m.copy()
    # The first half's translation shrunk 40x, as on tuning c0838.
    c_model[:11] = c_model[10] + (c_model[:11] - c_model[10]) / 40.0
    assert scale_spread(c_model, xyz_gps_m) > 10.0


def test_a_car_standing_through_a_stretch_or_too_few_cameras_say_nothing():
    xyz_gps_m = np.zeros((22, 3))
    xyz_gps_m[:, 0] = np.r_[np.zeros(8), np.linspace(0.0, 2.0, 14)]
    assert np.isnan(scale_spread(xyz_gps_m, xyz_gps_m))
    assert np.isnan(scale_spread(_turn_m(3), _turn_m(3)))

"""A sign's facing from the cameras that saw it (app.pipeline.geometry.facing)."""

from __future__ import annotations

import numpy as np
import pytest

from app.pipeline.geometry.facing import angle_between_deg, bearing_deg, facing_deg


def _approach(heading_deg: float, side_m: float, dists_m) -> tuple[np.ndarray, np.ndarray]:
    """A sign ``side_m`` right of a straight road and cameras approaching it along the road."""
    h = np.radians(heading_deg)
    fwd = np.array([np.sin(h), np.cos(h), 0.0])
    right = np.array([np.cos(h), -np.sin(h), 0.0])
    sign = side_m * right + np.array([0.0, 0.0, 2.0])
    cams = np.array([-d * fwd + np.array([0.0, 0.0, 1.5]) for d in dists_m])
    return sign, cams


@pytest.mark.parametrize("heading_deg", [0.0, 45.0, 170.0, 275.0])
def test_a_roadside_sign_faces_the_oncoming_driver(heading_deg):
    sign, cams = _approach(heading_deg, 4.0, np.linspace(40, 8, 20))
    est = facing_deg(sign, cams)
    # Facing the driver: opposite the heading, turned a little towards the road (to the left of
    # the reversed heading for a sign on the right).
    toward_driver = (heading_deg + 180.0) % 360.0
    assert 0.0 < angle_between_deg(est, toward_driver) < 15.0
    assert angle_between_deg(est, (toward_driver + 5.0) % 360) < \
        angle_between_deg(est, (toward_driver - 5.0) % 360)


def test_seen_from_both_sides_has_no_facing():
    sign = np.zeros(3)
    cams = np.array([[0.0, 20.0, 0.0], [0.0, 10.0, 0.0], [0.0, -10.0, 0.0], [0.0, -20.0, 0.0]])
    assert facing_deg(sign, cams) is None
    assert facing_deg(sign, sign[None, :]) is None


def test_bearings_and_their_difference():
    assert bearing_deg(np.array([0.0, 1.0, 0.0])) == pytest.approx(0.0)
    assert bearing_deg(np.array([1.0, 0.0, 5.0])) == pytest.approx(90.0)
    assert bearing_deg(np.array([0.0, -1.0, 0.0])) == pytest.approx(180.0)
    assert bearing_deg(np.array([-1.0, 0.0, 0.0])) == pytest.approx(270.0)
    assert angle_between_deg(350.0, 10.0) == pytest.approx(20.0)
    assert angle_between_deg(10.0, 190.0) == pytest.approx(180.0)


def test_fused_facing_is_the_weighted_circular_mean():
    from app.pipeline.geometry.facing import mean_facing_deg

    assert mean_facing_deg([350.0, 10.0], [1.0, 1.0]) == pytest.approx(0.0, abs=1e-9) or \
        mean_facing_deg([350.0, 10.0], [1.0, 1.0]) == pytest.approx(360.0)
    assert mean_facing_deg([80.0, None, 100.0], [3.0, 5.0, 1.0]) == pytest.approx(85.0, abs=0.2)
    assert mean_facing_deg([None], [1.0]) is None
    assert mean_facing_deg([0.0, 180.0], [1.0, 1.0]) is None

"""A camera's joint calibration over several journeys' windows (``cameras.calibrate_jointly``,
``colmap.joint``), on windows made by projecting points through a known camera: the adjustment
is COLMAP's own, run for real."""

from __future__ import annotations

import numpy as np
import pytest

from app.pipeline.cameras.calibrate_jointly import CameraWindow, calibrate_jointly
from app.pipeline.types import CameraModel
from tests.utils.results.turn_windows import turn_window

TRUE = CameraModel(1280, 720, 1000.0, 1004.0, 652.0, 355.0, -0.20, 0.08)


def _window(seed: int, camera: CameraModel = TRUE):
    return turn_window(camera, seed)


def _own(scale: float) -> CameraModel:
    """A window's own calibration: the truth with fx and fy times ``scale``."""
    return TRUE.replace(fx=TRUE.fx * scale, fy=TRUE.fy * scale)


def test_windows_fitted_together_recover_the_shared_camera():
    windows = [CameraWindow(f"j{k}", _own(s), _window(k)) for k, s in
               enumerate((1.015, 0.99, 1.02))]
    joint = calibrate_jointly(windows)
    assert joint.used == ["j0", "j1", "j2"] and not joint.left_out
    assert joint.camera.fx == pytest.approx(TRUE.fx, rel=0.003)
    # Turns about one vertical axis leave the pixel aspect loose: fy within its sigma's reach,
    # and the record says so.
    assert abs(joint.camera.fy - TRUE.fy) <= 2 * joint.sigma["fy"]
    assert not joint.fy_resolved
    assert abs(joint.camera.cx - TRUE.cx) < 2.0
    assert abs(joint.camera.cy - TRUE.cy) <= 2 * joint.sigma["cy"]  # as loose as fy
    assert joint.camera.k1 == pytest.approx(TRUE.k1, abs=0.01)
    assert all(r < 0.6 for r in joint.rms_px.values())
    # sigma: at least the windows' own spread over sqrt(3)
    spread = np.std([w.camera.fx for w in windows], ddof=1) / np.sqrt(3)
    assert joint.sigma["fx"] >= spread * 0.999


def test_a_wrong_window_is_left_out_and_named():
    windows = [CameraWindow("j0", _own(1.01), _window(0)),
               CameraWindow("wrong", _own(0.88), _window(1, TRUE.replace(fx=880.0, fy=884.0))),
               CameraWindow("j2", _own(0.995), _window(2))]
    joint = calibrate_jointly(windows)
    assert joint.used == ["j0", "j2"]
    assert "wrong" in joint.left_out and "disagrees" in joint.left_out["wrong"]
    assert joint.camera.fx == pytest.approx(TRUE.fx, rel=0.003)


def test_one_window_is_its_own_calibration_and_sizes_must_match():
    one = calibrate_jointly([CameraWindow("j0", _own(1.01), _window(0),
                                          (5.0, 5.0, 2.0, 2.0, 0.01, 0.01))])
    assert one.camera == _own(1.01) and one.sigma["fx"] == 5.0
    other = CameraWindow("j1", TRUE.replace(width=1920, height=1080), _window(1))
    with pytest.raises(ValueError, match="different image sizes"):
        calibrate_jointly([CameraWindow("j0", TRUE, _window(0)), other])

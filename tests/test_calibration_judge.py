"""How self-calibration judges a candidate window (no COLMAP: made-up window results)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.calibration import _judge
from app.pipeline.colmap_sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel

TRUE = CameraModel(1242, 375, 959.2, 952.9, 694.4, 241.7, -0.369, 0.158)


def _window(camera: CameraModel, *, error_px=0.15, registered=30, yaw_deg=80.0) -> WindowResult:
    T = np.tile(np.eye(4), (registered, 1, 1))
    T[:, :3, :3] = Rotation.from_euler("y", np.linspace(0.0, yaw_deg, registered)[:, None],
                                       degrees=True).as_matrix()
    return WindowResult([f"{i:06d}.png" for i in range(registered)], T, camera,
                        reprojection_error_px=error_px, n_input=30)


def test_a_right_calibration_passes():
    assert _judge(_window(TRUE), PipelineConfig()) is None


@pytest.mark.parametrize("fx, fy", [(877.0, 772.9), (816.1, 703.8)])
def test_a_wrong_minimum_with_unequal_focal_lengths_is_rejected(fx, fy):
    # Seen on turn-70 (2026-11-23): 0.56 px passes the error gate, fx/fy of 1.13-1.16 must not.
    wrong = CameraModel(1242, 375, fx, fy, 458.4, 253.4, -0.204, 0.037)
    assert "fx/fy" in _judge(_window(wrong, error_px=0.56), PipelineConfig())


@pytest.mark.parametrize("kwargs, reason", [
    ({"error_px": 1.5}, "reprojection error"),
    ({"registered": 20}, "frames registered"),
    ({"yaw_deg": 5.0}, "rotation"),
])
def test_a_poor_window_is_rejected_with_its_reason(kwargs, reason):
    assert reason in _judge(_window(TRUE, **kwargs), PipelineConfig())


def test_candidate_windows_span_the_turn_first_then_shift_and_stay_inside_the_journey():
    from app.pipeline.calibration import candidate_windows
    from app.pipeline.turns import TurnWindow

    cfg = PipelineConfig()
    turn = TurnWindow(start=0, end=70, vertex=37, angle_deg=99.0, rotation_deg=99.0)
    windows = candidate_windows([turn], 70, cfg)
    assert windows[0] == (37 - cfg.calib_window_frames // 2, 37 + cfg.calib_window_frames // 2)
    assert len(windows) == len(set(windows)) <= cfg.calib_max_candidates
    assert all(0 <= a < b <= 70 and b - a == cfg.calib_window_frames for a, b in windows)
    # A journey shorter than a window is mapped whole.
    assert candidate_windows([turn], 20, cfg) == [(0, 20)]

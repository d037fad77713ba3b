"""Poses of skipped frames, interpolated between the ego-motion's posed frames."""

import numpy as np
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.pose_interpolation import fill_skipped


def _circle_poses(frames: np.ndarray, radius_m: float = 10.0, step_rad: float = 0.1) -> np.ndarray:
    """A camera driving round a circle, looking along it (a car in a tight turn)."""
    a = frames * step_rad
    T = np.tile(np.eye(4), (len(frames), 1, 1))
    T[:, :3, 3] = np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a), np.zeros_like(a)])
    # cam z forward = the tangent, cam y down, cam x = z cross... right of the direction of travel
    heading = Rotation.from_euler("z", (a + np.pi / 2)[:, None])
    T[:, :3, :3] = (heading * Rotation.from_euler("xz", [-np.pi / 2, -np.pi / 2])).as_matrix()
    return T


def test_skipped_frames_get_the_pose_on_the_path_between_their_neighbours():
    posed = np.arange(0, 41, 2)  # every 2nd frame, as ego_frame_step = 2
    truth = _circle_poses(np.arange(41))
    frames, T = fill_skipped(posed, truth[posed], np.arange(41), max_gap=2)
    assert frames.tolist() == list(range(41))
    # A chord would miss the 10 m circle by 5 cm between posed frames 2 m apart; the spline by
    # under a millimetre, and the rotation is exact at a constant turn rate.
    assert np.abs(T[:, :3, 3] - truth[:, :3, 3]).max() < 0.001
    err = Rotation.from_matrix(T[:, :3, :3]) * Rotation.from_matrix(truth[:, :3, :3]).inv()
    assert np.degrees(err.magnitude()).max() < 1e-6
    # The posed frames keep their own poses.
    assert np.array_equal(T[posed], truth[posed])


def test_frames_across_a_gap_or_past_the_ends_are_left_without_a_pose():
    posed = np.array([10, 12, 14, 30, 32])  # frames 15-29: a window that failed
    poses = _circle_poses(posed)
    wanted = np.array([5, 11, 13, 20, 31, 33, 40])
    frames, T = fill_skipped(posed, poses, wanted, max_gap=2)
    assert frames.tolist() == [10, 11, 12, 13, 14, 30, 31, 32]
    assert len(T) == len(frames)
    # Off (0), nothing changes.
    frames, T = fill_skipped(posed, poses, wanted, max_gap=0)
    assert frames.tolist() == posed.tolist() and T is poses

"""``signmap bench real-ego``: ego-motion over a whole drive against its true poses (here a
rendered straight journey, whose truth file carries ``frames: [{frame, T_world_cam}]`` as the real
drives' poses files do)."""

import json

import numpy as np
from scipy.spatial.transform import Rotation

from bench.studies.real_ego import (evaluate, relative_errors, table, trajectory_rms_m,
                                    true_poses)


def test_relative_errors_see_a_turned_step_a_bent_direction_and_a_stretched_step():
    T = np.tile(np.eye(4), (6, 1, 1))
    T[:, 2, 3] = np.arange(6.0)  # one metre forward per frame
    same = relative_errors(2.0 * T, T, gap=1)  # another scale, the same motion
    assert all(np.allclose(e, 0.0, atol=1e-9) for e in same)
    est = T.copy()
    est[3:, :3, :3] = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()
    est[5, 0, 3] = 0.2  # the last step bends sideways...
    est[5, 2, 3] = 5.5  # ...and is half as long again
    rot, direction, dev = relative_errors(est, T, gap=1)
    assert np.allclose(rot, [0, 0, 1, 0, 0], atol=1e-6)
    assert direction[-1] > 5.0 and np.allclose(direction[:3], 0.0, atol=1e-6)
    assert dev[-1] > 0.4 and np.allclose(dev[:3], 0.0, atol=1e-9)


def test_a_straight_drive_is_mapped_whole_and_its_motion_matches_the_truth(
        straight_journey_bundle, tmp_path):
    bundle, truth = straight_journey_bundle
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps(truth["camera"]))
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"frames": truth["frames"]}))
    figures, summary = evaluate(bundle, camera, poses, tmp_path / "work")
    assert figures and summary.startswith(f"{len(figures)} of {len(figures)} windows")
    for f in figures:
        done, asked = map(int, f.registration.split(" ")[0].split("/"))
        assert done == asked, f.registration
    rot = np.concatenate([f.rot_err_deg for f in figures])
    direction = np.concatenate([f.dir_err_deg for f in figures])
    dev = np.concatenate([f.scale_dev for f in figures])
    assert len(rot) >= 10
    assert np.median(rot) < 0.1 and np.median(direction) < 1.0 and np.percentile(dev, 90) < 0.05
    assert all(f.trajectory_rms_m < 0.2 for f in figures), [f.trajectory_rms_m for f in figures]
    assert table("straight", figures, summary).splitlines()[-1].startswith("| all | |")


def test_trajectory_error_is_taken_after_the_best_similarity():
    t = np.linspace(0.0, np.pi / 2, 30)
    true = np.column_stack([20 * np.sin(t), 20 * (1 - np.cos(t)), np.zeros(30)])  # a flat turn
    R = Rotation.from_euler("xyz", [30, -20, 75], degrees=True)
    est = R.apply(true) * 0.05 + [3.0, -1.0, 2.0]
    assert trajectory_rms_m(est, true) < 1e-9
    bent = est.copy()
    bent[15:] += R.apply([0.0, 0.0, 1.0]) * 0.05  # half the path 1 m off the plane
    assert 0.15 < trajectory_rms_m(bent, true) < 0.5  # a tilt takes some of the 1 m step


def test_true_poses_read_both_files_kitti_gives(tmp_path):
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, 0, 3] = [0.0, 1.0, 2.0]
    by_frame = tmp_path / "frames.json"
    by_frame.write_text(json.dumps({"frames": [{"frame": "000001", "T_world_cam": T[1].tolist()}]}))
    assert true_poses(by_frame, ["000000", "000001"])[0] is None
    assert np.allclose(true_poses(by_frame, ["000000", "000001"])[1], T[1])
    in_order = tmp_path / "list.json"
    in_order.write_text(json.dumps({"T_enu_cam": T[:2].tolist()}))
    poses = true_poses(in_order, ["000000", "000001", "000002"])
    assert np.allclose(poses[1], T[1]) and poses[2] is None

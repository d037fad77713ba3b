"""A broken window mended: a run of bad fixes left out, a bent reconstruction aligned in parts,
and what is neither left broken."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import Sim3
from app.pipeline.steps import align
from app.pipeline.steps.align.mend import mend_window
from app.pipeline.steps.ego_motion import WindowPoses

NOISE_M = 0.27
LIMIT_M = 5 * NOISE_M


def _road(n: int = 90) -> np.ndarray:
    """(n, 4, 4) T_world_cam along 40 m straight, then a 90-degree left turn of 15 m radius,
    1 m apart, cameras level and looking along the road."""
    s = np.arange(n, dtype=float)
    xy = np.where(s[:, None] < 40, np.column_stack([s, 0 * s]), 0)
    a = (s - 40) / 15.0
    turn = s >= 40
    xy[turn] = np.column_stack([40 + 15 * np.sin(a[turn]), 15 - 15 * np.cos(a[turn])])
    heading = np.where(turn, a, 0.0)
    T = np.tile(np.eye(4), (n, 1, 1))
    z = np.column_stack([np.cos(heading), np.sin(heading), 0 * heading])
    x = np.cross(z, [0.0, 0.0, 1.0])
    T[:, :3, :3] = np.stack([x, np.cross(z, x), z], axis=2)
    T[:, :3, 3] = np.column_stack([xy, np.full(n, 1.5)])
    return T


def _window(T_world_cam: np.ndarray, model_from_world: Sim3) -> WindowPoses:
    return WindowPoses((0, len(T_world_cam)), np.arange(len(T_world_cam)),
                       model_from_world.apply_poses(T_world_cam))


def _aligned(poses: WindowPoses, gps: np.ndarray) -> align.AlignedWindow:
    [w] = align.align_windows([poses], gps, joint=False, max_independent_rms_m=LIMIT_M)
    return w


MODEL = Sim3(0.2, Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix(), np.array([5.0, -2, 1]))


@pytest.fixture
def truth():
    T = _road()
    gps = T[:, :3, 3] + np.random.default_rng(0).normal(scale=NOISE_M, size=(len(T), 3))
    return T, gps


def test_a_run_of_bad_fixes_is_left_out_and_the_window_kept_whole(truth):
    T, gps = truth
    gps = gps.copy()
    gps[30:46, 1] += 6.0  # multipath: 16 fixes 6 m to the left, good fixes on both sides
    window = _aligned(_window(T, MODEL), gps)
    assert window.info["broken"] and window.info["rms_m"] > LIMIT_M

    fix = mend_window(window, gps, LIMIT_M)
    assert fix.mended and len(fix.pieces) == 1
    assert "GPS was off" in fix.how and "30-45" in fix.how
    [piece] = fix.pieces
    assert piece.info["rms_m"] < 0.6 * LIMIT_M
    # Every frame, the run's too, lies where it was: the reconstruction was whole.
    err = np.linalg.norm(piece.T_world_cam[:, :3, 3] - T[:, :3, 3], axis=1)
    assert err.max() < 0.25


def test_a_bent_reconstruction_is_aligned_in_parts(truth):
    T, gps = truth
    poses = _window(T, MODEL)
    # The reconstruction's scale jumps by 40 % at frame 50, in the turn.
    bent = poses.T_model_cam.copy()
    pivot = bent[50, :3, 3]
    bent[50:, :3, 3] = pivot + 1.4 * (bent[50:, :3, 3] - pivot)
    window = _aligned(WindowPoses(poses.window, poses.frame_idx, bent), gps)
    assert window.info["broken"]

    fix = mend_window(window, gps, LIMIT_M)
    assert fix.mended and "aligned in 2 parts" in fix.how
    assert len(fix.pieces) == 2 and not any(p.info["broken"] for p in fix.pieces)
    assert abs(fix.pieces[1].poses.frame_idx[0] - 50) <= 3
    for p in fix.pieces:
        err = np.linalg.norm(p.T_world_cam[:, :3, 3] - T[p.poses.frame_idx, :3, 3], axis=1)
        assert np.median(err) < 0.3


def test_a_reconstruction_that_is_noise_stays_broken(truth):
    T, gps = truth
    poses = _window(T, MODEL)
    scrambled = poses.T_model_cam.copy()
    scrambled[:, :3, 3] += np.random.default_rng(1).normal(scale=3.0, size=(len(T), 3))
    window = _aligned(WindowPoses(poses.window, poses.frame_idx, scrambled), gps)

    fix = mend_window(window, gps, LIMIT_M)
    assert not fix.mended and fix.how.startswith("not mended")
    assert [p.info["broken"] for p in fix.pieces] == [True]
    assert fix.pieces[0].info["rms_m"] > LIMIT_M


def test_align_windows_mends_and_tells(truth):
    T, gps = truth
    gps = gps.copy()
    gps[30:46, 1] += 6.0
    told = []
    aligned = align.align_windows([_window(T, MODEL)], gps, max_independent_rms_m=LIMIT_M,
                                  mend_broken=True, on_broken=lambda w, fix: told.append(fix))
    assert len(told) == 1 and told[0].mended
    assert aligned[0].info["rms_m"] < LIMIT_M and "mend" in aligned[0].info
    # Not asked to mend: the same window stays broken, as before.
    [plain] = align.align_windows([_window(T, MODEL)], gps, max_independent_rms_m=LIMIT_M)
    assert plain.info["broken"] and plain.info["rms_m"] > LIMIT_M


def test_a_run_at_the_windows_start_is_left_out_when_a_neighbour_vouches(truth):
    T, clean = truth
    gps = clean.copy()
    gps[45:55, 1] += 5.0  # a run at the start of the second window, the end of the first
    second = _aligned(WindowPoses((45, 80), np.arange(45, 80), MODEL.apply_poses(T[45:80])), gps)
    assert second.info["broken"]
    # The first window, aligned where its fixes were good, poses the run's first frames.
    first = _aligned(WindowPoses((0, 48), np.arange(48), MODEL.apply_poses(T[:48])), clean)

    fix = mend_window(second, gps, LIMIT_M, neighbours=[first])
    assert fix.mended and "neighbouring window agrees" in fix.how and "45-54" in fix.how
    err = np.linalg.norm(fix.pieces[0].T_world_cam[:, :3, 3] - T[45:80, :3, 3], axis=1)
    assert err.max() < 0.5  # 25 fixes of 0.27 m noise hold the run's end, extrapolated, so far


def test_a_piece_that_follows_bad_fixes_away_from_its_neighbour_stays_broken(truth):
    T, clean = truth
    gps = clean.copy()
    gps[45:55, 1] += 5.0
    second = _aligned(WindowPoses((45, 80), np.arange(45, 80), MODEL.apply_poses(T[45:80])), gps)
    # A neighbour pulled ~1.5 m at its end by the same run cannot vouch for it; split, the
    # run's ten frames would follow the bad fixes, 5 m from where the neighbour poses them.
    first = _aligned(WindowPoses((0, 48), np.arange(48), MODEL.apply_poses(T[:48])), gps)

    fix = mend_window(second, gps, LIMIT_M, neighbours=[first])
    assert "GPS was off" not in fix.how
    for p in fix.pieces:
        err = np.linalg.norm(p.T_world_cam[:, :3, 3] - T[p.poses.frame_idx, :3, 3], axis=1)
        assert p.info["broken"] or err.max() < 0.5, (p.poses.window, err.max())
    assert fix.mended  # what follows the run is kept


def test_a_broken_window_is_told_even_when_mending_is_off(truth):
    T, gps = truth
    gps = gps.copy()
    gps[30:46, 1] += 6.0
    told = []
    align.align_windows([_window(T, MODEL)], gps, max_independent_rms_m=LIMIT_M,
                        on_broken=lambda w, fix: told.append((w.info["rms_m"], fix)))
    [(rms_m, fix)] = told
    assert rms_m > LIMIT_M and not fix.mended and "off" in fix.how


def test_a_split_that_would_follow_bad_fixes_leaves_the_path_jumping_and_is_refused(truth):
    T, gps = truth
    gps = gps.copy()
    gps[40:, 1] += 6.0  # the window's last 50 fixes off: more than the good ones
    window = _aligned(_window(T, MODEL), gps)
    assert window.info["broken"]

    fix = mend_window(window, gps, LIMIT_M)
    # Either side alone follows its fixes, but the two do not meet: nothing is kept.
    assert not fix.mended, fix.how

"""A broken window mended: a run of bad fixes left out; a bent end cut off, not followed; a
reconstruction that broke left broken."""

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
    assert fix.mended and "GPS was off" in fix.how and "within 30-45" in fix.how
    assert fix.window.info["rms_m"] < 0.6 * LIMIT_M
    # Every frame, the run's too, lies where it was: the reconstruction was whole.
    np.testing.assert_array_equal(fix.window.poses.frame_idx, np.arange(90))
    err = np.linalg.norm(fix.window.T_world_cam[:, :3, 3] - T[:, :3, 3], axis=1)
    assert err.max() < 0.25


def _bent(T: np.ndarray, at: int, scale: float) -> WindowPoses:
    """The road's reconstruction whose scale changes by ``scale`` from frame ``at`` on."""
    poses = _window(T, MODEL)
    bent = poses.T_model_cam.copy()
    pivot = bent[at, :3, 3]
    bent[at:, :3, 3] = pivot + scale * (bent[at:, :3, 3] - pivot)
    return WindowPoses(poses.window, poses.frame_idx, bent)


def test_a_bent_end_is_cut_off_not_followed(truth):
    T, gps = truth
    window = _aligned(_bent(T, 65, 1.4), gps)  # the last 25 frames' scale 40 % off
    assert window.info["broken"]

    fix = mend_window(window, gps, LIMIT_M)
    assert fix.mended and "left unposed" in fix.how
    kept = fix.window.poses.frame_idx
    assert kept[0] == 0 and 64 <= kept[-1] < 75
    err = np.linalg.norm(fix.window.T_world_cam[:, :3, 3] - T[kept, :3, 3], axis=1)
    assert err[kept < 65].max() < 0.3
    # The bend's first frames follow their fixes within the limit, and are kept that far off.
    assert err.max() < LIMIT_M + 3 * NOISE_M


@pytest.mark.parametrize("bent", [True, False])
def test_what_no_similarity_follows_for_two_thirds_stays_broken(truth, bent):
    T, gps = truth
    if bent:  # bent in the middle: neither side is two thirds of it
        poses = _bent(T, 45, 1.4)
    else:  # noise
        poses = _window(T, MODEL)
        poses = WindowPoses(poses.window, poses.frame_idx, poses.T_model_cam.copy())
        poses.T_model_cam[:, :3, 3] += np.random.default_rng(1).normal(scale=3.0, size=(90, 3))
    window = _aligned(poses, gps)

    fix = mend_window(window, gps, LIMIT_M)
    assert not fix.mended and fix.how.startswith("not mended")
    assert fix.window.info["broken"] and fix.window.info["rms_m"] > LIMIT_M


def test_when_most_fixes_are_off_the_window_stays_broken(truth):
    T, gps = truth
    gps = gps.copy()
    gps[40:, 1] += 6.0  # the window's last 50 fixes off: more than the good ones
    fix = mend_window(_aligned(_window(T, MODEL), gps), gps, LIMIT_M)
    assert not fix.mended, fix.how


def test_align_windows_mends_and_tells(truth):
    T, gps = truth
    gps = gps.copy()
    gps[30:46, 1] += 6.0
    told = []
    aligned = align.align_windows([_window(T, MODEL)], gps, max_independent_rms_m=LIMIT_M,
                                  mend_broken=True, on_broken=lambda w, fix: told.append(fix))
    assert len(told) == 1 and told[0].mended
    assert aligned[0].info["rms_m"] < LIMIT_M and "mend" in aligned[0].info
    # Not asked to mend: the same window stays broken, as before, and is still told.
    told.clear()
    [plain] = align.align_windows([_window(T, MODEL)], gps, max_independent_rms_m=LIMIT_M,
                                  on_broken=lambda w, fix: told.append((w.info["rms_m"], fix)))
    assert plain.info["broken"] and plain.info["rms_m"] > LIMIT_M
    [(rms_m, fix)] = told
    assert rms_m > LIMIT_M and not fix.mended and "off" in fix.how


def test_a_run_at_the_windows_start_keeps_its_poses_where_a_neighbour_vouches(truth):
    T, clean = truth
    gps = clean.copy()
    gps[45:55, 1] += 5.0  # a run at the start of the second window, the end of the first
    second = _aligned(WindowPoses((45, 80), np.arange(45, 80), MODEL.apply_poses(T[45:80])), gps)
    assert second.info["broken"]
    # The first window, aligned where its fixes were good, poses the run's first frames.
    first = _aligned(WindowPoses((0, 48), np.arange(48), MODEL.apply_poses(T[:48])), clean)

    fix = mend_window(second, gps, LIMIT_M, neighbours=[first])
    assert fix.mended and "neighbouring window agrees" in fix.how and "45-54" in fix.how
    np.testing.assert_array_equal(fix.window.poses.frame_idx, np.arange(45, 80))
    err = np.linalg.norm(fix.window.T_world_cam[:, :3, 3] - T[45:80, :3, 3], axis=1)
    assert err.max() < 0.6  # 25 fixes of 0.27 m noise hold the run's end, extrapolated, so far

    # A neighbour pulled ~1.5 m at its end by the same run cannot vouch: the run's frames are
    # left unposed, the rest kept.
    pulled = _aligned(WindowPoses((0, 48), np.arange(48), MODEL.apply_poses(T[:48])), gps)
    fix = mend_window(second, gps, LIMIT_M, neighbours=[pulled])
    assert fix.mended and "left unposed" in fix.how
    assert fix.window.poses.frame_idx[0] == 55

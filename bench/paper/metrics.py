"""Accuracy metrics of one run against a synthetic journey's truth (``truth.json`` as a dict):
calibration errors, placed signs matched to true ones and their errors, trajectory ATE, recall.

Frames: ``truth_enu`` is the synthetic world's ENU frame (origin ``truth["origin"]``); a pipeline
result lives in its own ENU frame at the journey's first (noisy) GPS fix, so trajectories are
carried over through WGS84 before they are compared.
"""

from __future__ import annotations

import resource
import warnings
from typing import Callable

import numpy as np

from app.pipeline.geometry.facing import angle_between_deg
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.geometry.similarity import umeyama
from app.pipeline.types import Calibration, CameraModel, JourneyResult
from app.synth.camera.detect import project
from app.synth.camera.lens import distort_radius, undistort_normalized

CALIB_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2")


def calibration_errors_pct(params: dict, truth: dict) -> dict[str, float]:
    """Signed % error of each calibration parameter against the true camera."""
    cam = truth["camera"]
    return {k: 100.0 * (params[k] - cam[k]) / abs(cam[k]) for k in CALIB_KEYS}


# A placed sign whose track is not a true sign's (the detector's false tracks, or tracks the
# pipeline associated itself when the bundle had no track ids) is matched to the nearest true sign
# within this horizontal distance; farther than that it is a false sign.
MATCH_RADIUS_M = 3.0


def match_signs(result: JourneyResult, truth: dict, radius_m: float = MATCH_RADIUS_M
                ) -> tuple[list[tuple[object, dict]], list[dict]]:
    """(matched, unmatched): each placed sign paired with its true sign (by track id when the
    track is a true sign's, else the nearest unclaimed true sign within ``radius_m``), and one
    record per placed sign left over: a false sign (no true sign near) or a duplicate (the near
    one is taken by another placed sign)."""
    enu = truth_frame(truth)
    by_track = {str(s["track_id"]): s for s in truth["signs"]
                if s.get("track_id") not in (None, "")}
    by_id = {truth_id(s): s for s in truth["signs"]}
    true_xy = {i: np.asarray(s["xyz_enu"], float)[:2] for i, s in by_id.items()}
    matched, claimed, pending = [], set(), []
    for sign in result.signs:
        t = by_track.get(sign.track_id)
        if t is not None and truth_id(t) not in claimed:
            matched.append((sign, t))
            claimed.add(truth_id(t))
        else:
            pending.append(sign)
    unmatched = []
    for sign in pending:
        xy = enu.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0][:2]
        dist = {i: float(np.linalg.norm(xy - t)) for i, t in true_xy.items()}
        free = {i: d for i, d in dist.items() if i not in claimed and d <= radius_m}
        if free:
            best = min(free, key=free.get)
            matched.append((sign, by_id[best]))
            claimed.add(best)
            continue
        nearest = min(dist.values(), default=float("inf"))
        unmatched.append({"track_id": sign.track_id, "class": sign.cls,
                          "nearest_true_m": nearest,
                          "kind": "duplicate" if nearest <= radius_m else "false"})
    return matched, unmatched


def truth_id(sign: dict) -> str:
    """A true sign's id (older truth files have only its track id)."""
    return str(sign.get("id", sign.get("track_id")))


def truth_frame(truth: dict):
    """The truth's local ENU frame (its origin), in which ``xyz_enu`` and camera poses are."""
    o = truth["origin"]
    return frame_at(o["lat"], o["lon"], o["alt_m"])


def sign_errors(result: JourneyResult, truth: dict) -> dict[str, dict[str, float]]:
    """Per placed sign matched to a true one (``match_signs``), by the placed sign's track id:
    absolute error (m, ENU distance to the true plate centre), relative error (m, mean over
    observing frames of the camera-frame position error), facing error, horizontal error against
    its own 95 % radius, and where along the journey it was seen."""
    enu = truth_frame(truth)
    s_by_frame = {f["frame"]: f["s_m"] for f in truth.get("frames", [])}
    out = {}
    for sign, t in match_signs(result, truth)[0]:
        est = enu.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0]
        true = np.asarray(t["xyz_enu"], dtype=float)
        true_cam = {ob["frame"]: np.array([ob["x"], ob["y"], ob["z"]]) for ob in t["observations"]}
        pairs = [(np.array(ob.p_cam), true_cam[ob.frame_id]) for ob in sign.observations
                 if ob.frame_id in true_cam]
        rel = [np.linalg.norm(p - q) for p, q in pairs]
        # Range and range ratio: a reconstruction scaled wrong errs along the ray, in proportion
        # to the range; triangulation noise errs across it too.
        range_m = [np.linalg.norm(q) for _, q in pairs]
        range_ratio = [np.linalg.norm(p) / np.linalg.norm(q) for p, q in pairs]
        facing_err = (angle_between_deg(sign.facing_deg, t["facing_deg"])
                      if sign.facing_deg is not None and "facing_deg" in t else float("nan"))
        h_err_m = float(np.linalg.norm((est - true)[:2]))
        s_m = [s_by_frame[ob.frame_id] for ob in sign.observations if ob.frame_id in s_by_frame]
        out[sign.track_id] = {"truth_id": truth_id(t), "abs_m": float(np.linalg.norm(est - true)),
                              "rel_m": float(np.mean(rel)) if rel else float("nan"),
                              "range_m": float(np.mean(range_m)) if rel else float("nan"),
                              "range_ratio": (float(np.median(range_ratio)) if rel
                                              else float("nan")),
                              "std_m": float(sign.std_m), "facing_err_deg": facing_err,
                              "h_err_m": h_err_m, "r95_h_m": sign.r95_h_m,
                              "within_r95": (None if sign.r95_h_m is None
                                             else bool(h_err_m <= sign.r95_h_m)),
                              # Distance along the journey where it was seen (error vs distance).
                              "s_m": float(np.mean(s_m)) if s_m else float("nan"),
                              # Per observation (true range, camera-frame error), metres: the
                              # relative error against range.
                              "obs_range_err_m": [[round(float(r), 3), round(float(e), 4)]
                                                  for r, e in zip(range_m, rel)],
                              **_uncertainty_parts(sign)}
    return out


def _uncertainty_parts(sign) -> dict:
    """The terms of the sign's covariance, so a bench can weigh them again (uncertainty knobs)."""
    u = sign.uncertainty
    if u is None:
        return {}
    return {"cov_tri_h_m2": np.round(u.cov_triangulation_enu[:2, :2], 8).tolist(),
            "georef_noise_m2": float(u.georef.averaged_noise_m2),
            "georef_floor_weight": float(u.georef.floor_weight),
            "georef_residual_m2": float(u.georef.residual_m2)}


ATE_SNIPPET_FRAMES = 5


def truth_centres_enu(truth: dict) -> dict[str, np.ndarray]:
    """Frame id -> true camera centre (3,) in truth ENU metres."""
    return {f["frame"]: np.asarray(f["T_world_cam"], dtype=float)[:3, 3] for f in truth["frames"]}


def result_to_truth_enu(result: JourneyResult, xyz_enu: np.ndarray, truth: dict) -> np.ndarray:
    """(M,3) points of ``result``'s ENU frame -> (M,3) in truth ENU."""
    if len(xyz_enu) == 0:
        return np.zeros((0, 3))
    lat0, lon0, alt0 = result.origin_lat_lon_alt
    lat, lon, alt = frame_at(lat0, lon0, alt0).to_geodetic(xyz_enu)
    return truth_frame(truth).to_local(lat, lon, alt)


def aligned_rmse_m(xyz_est: np.ndarray, xyz_true: np.ndarray) -> float:
    """RMSE (m) of (M,3) estimated positions after the least-squares similarity onto the truth.

    Points that fix no rotation (a straight snippet) fall back to a rigid fit: the rotation about
    the line then moves no point, so the error is the same.
    """
    try:
        sim = umeyama(xyz_est, xyz_true)
    except ValueError:
        with warnings.catch_warnings():  # SciPy warns that the roll is undetermined: known
            warnings.simplefilter("ignore", UserWarning)
            sim = umeyama(xyz_est, xyz_true, with_scale=False)
    return float(np.sqrt(np.mean(np.sum((sim.apply(xyz_est) - xyz_true) ** 2, axis=1))))


def snippet_rmse_m(frame_idx: np.ndarray, xyz_est: np.ndarray, xyz_true: np.ndarray,
                   length: int = ATE_SNIPPET_FRAMES) -> np.ndarray:
    """Aligned RMSE of every run of ``length`` consecutive posed frames (ATE-5 of Zhou et al.
    2017).

    ``frame_idx`` (M,) are the journey frame indices of the rows. The pipeline may pose every n-th
    frame only: a snippet is ``length`` consecutive rows whose frame indices advance by the usual
    step (the median one), so it never spans a gap or the seam of two reconstructed windows.
    """
    steps = np.diff(frame_idx)
    if not np.any(steps > 0):
        return np.zeros(0)
    step = np.median(steps[steps > 0])
    out = []
    for start in range(len(frame_idx) - length + 1):
        if np.all(steps[start:start + length - 1] == step):
            out.append(aligned_rmse_m(xyz_est[start:start + length],
                                      xyz_true[start:start + length]))
    return np.asarray(out)


def trajectory_metrics(result: JourneyResult, truth: dict) -> dict[str, float]:
    """ATE of the estimated camera centres: ``ate_gps_m`` as georeferenced by the run (no further
    alignment), ``ate_full_m`` after one similarity onto the truth (Horn), ``ate5_mean_m`` /
    ``ate5_std_m`` over 5-frame snippets, ``n_posed`` frames with a pose."""
    centres = truth_centres_enu(truth)
    ids = [f for f in result.trajectory_frame_ids if f in centres]
    nan = float("nan")
    if len(ids) < 3:
        return {"n_posed": len(ids), "ate_gps_m": nan, "ate_full_m": nan, "ate5_mean_m": nan,
                "ate5_std_m": nan}
    keep = np.array([f in centres for f in result.trajectory_frame_ids])
    xyz_est = result_to_truth_enu(result, np.asarray(result.trajectory_enu)[keep], truth)
    xyz_true = np.array([centres[f] for f in ids])
    order = {f["frame"]: i for i, f in enumerate(truth["frames"])}
    snippets = snippet_rmse_m(np.array([order[f] for f in ids]), xyz_est, xyz_true)
    return {
        "n_posed": len(set(ids)),
        "ate_gps_m": float(np.sqrt(np.mean(np.sum((xyz_est - xyz_true) ** 2, axis=1)))),
        "ate_full_m": aligned_rmse_m(xyz_est, xyz_true),
        "ate5_mean_m": float(snippets.mean()) if len(snippets) else nan,
        "ate5_std_m": float(snippets.std()) if len(snippets) else nan,
    }


# Issue 12's recall rule: a sign detected in at least 5 frames with a box at least 12 px tall must
# be placed (more than the pipeline's min_track_frames, 3).
RECALL_MIN_FRAMES = 5


def mappable_ids(truth: dict, min_frames: int, min_height_px: float = 12.0) -> list[str]:
    """Ids of the true signs the pipeline must place: detected (not missed) in at least
    ``min_frames`` frames with a box at least ``min_height_px`` tall."""
    missed = {(m["frame"], str(m.get("track_id", ""))) for m in truth.get("missed_detections", [])}
    out = []
    for s in truth["signs"]:
        frames = {o["frame"] for o in s["observations"]
                  if (o["frame"], str(s.get("track_id", ""))) not in missed
                  and ("box_true" not in o or o["box_true"][3] - o["box_true"][1] >= min_height_px)}
        if len(frames) >= min_frames:
            out.append(truth_id(s))
    return out


def mappable_signs(truth: dict, min_frames: int) -> int:
    """How many true signs the pipeline must place (``mappable_ids``)."""
    return len(mappable_ids(truth, min_frames))


def sign_summary(errors: dict[str, dict[str, float]]) -> dict[str, float]:
    """Mean and median relative / absolute error (m) over the signs of ``sign_errors``."""
    rel = np.array([e["rel_m"] for e in errors.values()], dtype=float)
    abs_m = np.array([e["abs_m"] for e in errors.values()], dtype=float)
    rel = rel[np.isfinite(rel)]
    facing = np.array([e.get("facing_err_deg", np.nan) for e in errors.values()], dtype=float)
    facing = facing[np.isfinite(facing)]

    def stat(fn, a):
        return float(fn(a)) if len(a) else float("nan")
    return {"n_signs": len(errors), "rel_mean_m": stat(np.mean, rel),
            "rel_median_m": stat(np.median, rel), "abs_mean_m": stat(np.mean, abs_m),
            "abs_median_m": stat(np.median, abs_m),
            "facing_median_deg": stat(np.median, facing)}


def _grid_px(true: CameraModel, n: int) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0.0, true.width - 1.0, n),
                       np.linspace(0.0, true.height - 1.0, n))
    return np.stack([u, v], axis=-1).reshape(-1, 2)


def distortion_error_px(est: dict[str, float], true: CameraModel, n: int = 41,
                        within_px: float | None = None) -> float:
    """The largest distance over the image (an ``n`` x ``n`` grid of its pixels; those within
    ``within_px`` of the principal point, if given) between where ``est``'s k1, k2 and ``true``'s
    put a ray, both through ``true``'s fx, fy, cx, cy: what an error in the distortion costs in
    the image. k1's per cent does not say it: on a lens with k1 +0.003, k1 86 % off moved no pixel
    by more than 0.5 px, while k1 about 1 % off and k2 off left 6-7 px at the corners of two wide
    images of the corpus."""
    px = _grid_px(true, n)
    if within_px is not None:
        px = px[np.hypot(px[:, 0] - true.cx, px[:, 1] - true.cy) <= within_px]
    xy_u = undistort_normalized(true, px)
    r_u = np.maximum(np.hypot(xy_u[:, 0], xy_u[:, 1]), 1e-12)
    r_d_est = distort_radius(r_u, est["k1"], est["k2"])
    shift = (r_d_est - distort_radius(r_u, true.k1, true.k2)) / r_u
    return float(np.max(np.hypot(true.fx * xy_u[:, 0] * shift, true.fy * xy_u[:, 1] * shift)))


def projection_error_px(est: dict[str, float], true: CameraModel, n: int = 41) -> float:
    """The largest distance over the image between where the whole estimated camera (focal
    length, principal point and distortion) and the true one put the same ray. A focal length
    off and a distortion that makes up for it cost less here than ``distortion_error_px`` says:
    on a wide lens, fx 0.25 % off moves its edge by ~2 px, which k1 can take back."""
    xy_u = undistort_normalized(true, _grid_px(true, n))
    rays = np.column_stack([xy_u, np.ones(len(xy_u))])
    estimated = CameraModel.from_params(true.width, true.height, est)
    return float(np.max(np.linalg.norm(project(estimated, rays) - project(true, rays), axis=1)))


def true_camera(true: dict) -> CameraModel | None:
    """A true camera given as a dict (a corpus journey's parameters, a truth file's camera):
    None unless it has the image size and all six intrinsics."""
    keys = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2")
    if any(true.get(k) is None for k in keys):
        return None
    return CameraModel.from_params(int(true["width"]), int(true["height"]), true)


def true_distortion_error_px(est: dict[str, float], true: dict) -> float | None:
    """``distortion_error_px`` against ``true_camera(true)``; None without one."""
    camera = true_camera(true)
    return None if camera is None else distortion_error_px(est, camera)


def calibration_summary(cal: Calibration, errors: Callable[[dict], dict], *, camera_key: str,
                        errors_key: str) -> dict:
    """The estimated camera and its stage-1 start with their ``errors(params)``; the key names
    are those of the JSON the bench (``final``, ``errors_pct``) or the corpus bench writes."""
    stage1 = cal.stage1.params() if cal.stage1 is not None else None
    return {"source": cal.source, camera_key: cal.camera.params(),
            errors_key: errors(cal.camera.params()), "stage1": stage1,
            f"stage1_{errors_key}": errors(stage1) if stage1 else None,
            "reprojection_error_px": float(cal.reprojection_error_px)}


def calibration_metrics(result: JourneyResult, truth: dict) -> dict:
    return calibration_summary(result.calibration, lambda p: calibration_errors_pct(p, truth),
                               camera_key="final", errors_key="errors_pct")


def evaluate_result(result: JourneyResult, truth: dict) -> dict:
    """Calibration, trajectory and sign metrics of one run (JSON-ready)."""
    errors = sign_errors(result, truth)
    unmatched = match_signs(result, truth)[1]
    return {"calibration": calibration_metrics(result, truth),
            "ate": trajectory_metrics(result, truth),
            "signs": {**sign_summary(errors),
                      "n_false": sum(u["kind"] == "false" for u in unmatched),
                      "n_duplicate": sum(u["kind"] == "duplicate" for u in unmatched)},
            "sign_errors": errors, "unmatched_signs": unmatched,
            "rejected": {r.track_id: r.reason for r in result.rejected}}


def cpu_seconds() -> float:
    """User + system CPU time of this process and its waited-for children: unlike wall time, it
    hardly depends on what else the machine is running."""
    own, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def peak_rss_mb() -> dict[str, float]:
    """Peak resident memory (MB) of this process and of its largest waited-for child."""
    kb = 1024.0  # Linux reports ru_maxrss in KiB
    return {"self_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kb,
            "children_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / kb}

"""``signmap bench pose-error``: where a placed sign's relative error comes from.

The relative (per-frame camera) error of a sign is its position error in the cameras that saw
it. It has three sources: the detections themselves (box noise, a triangulation from rays
nearly along the direction of travel), the estimated camera rotations between the sign's
frames, and the estimated camera centres between them (including the scale the GPS gave the
window). This re-triangulates each placed sign of a kept corpus run (``signmap bench corpus
--keep-reconstructions DIR``) from its own detections with four sets of poses over its frames:

- ``placed``: the pipeline's own result (the corpus bench's relative error);
- ``true poses``: the renderer's camera poses: what the detections alone cost (the floor);
- ``true poses, every frame``: the same from every frame the sign was detected in, posed or
  not (the ego-motion poses every ``ego_frame_step``-th frame);
- ``est. rotations``: estimated rotations (brought onto the truth by their mean offset, which
  no relative error sees) with true centres;
- ``est. centres``: true rotations with estimated centres.

and reports per GPS kind the mean of each, the relative rotation error between a sign's first
and last frame, and the scale error of the camera path over its frames, beside the GPS's own.

Frames: ``world`` is the truth's ENU frame; estimated centres are brought into it by geodetic
conversion; rotations between the two ENU frames differ by far less than the errors measured.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.triangulation import TriangulationError, triangulate, undistort_pixels
from app.pipeline.run import georeference
from app.pipeline.types import PipelineError
from bench.corpus import replay
from bench.corpus.report import GPS_KINDS, gps_kind
from bench.paper.metrics import match_signs, result_to_truth_enu

POSE_SETS = ("placed", "true poses", "true poses, every frame", "est. rotations",
             "est. centres")


@dataclass(frozen=True)
class SignPoseError:
    """One placed sign: ``rel_m`` per POSE_SETS name (m, mean over its frames of the camera-frame
    position error); ``rot_err_deg`` the error of the rotation between its first and last frame;
    ``path_scale_err`` / ``gps_scale_err`` estimated / GPS distance between those frames over
    the true one, minus 1."""

    journey: str
    track_id: str
    gps: str
    rel_m: dict[str, float]
    rot_err_deg: float
    path_scale_err: float
    gps_scale_err: float


def _poses(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(R), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, c
    return T


def _rel_m(T_world_cam: np.ndarray, px_undist: np.ndarray, K: np.ndarray,
           p_cam_true: np.ndarray) -> float:
    """Mean camera-frame error of the sign triangulated from these poses (no gates: the
    point is to see the error, not to judge the sign)."""
    try:
        point = triangulate(T_world_cam, px_undist, K, max_rms_px=np.inf, min_ray_angle_deg=0.0,
                            max_shift_sigma=np.inf)
    except TriangulationError:
        return float("nan")
    return float(np.mean(np.linalg.norm(point.p_cam - p_cam_true, axis=1)))


def sign_pose_errors(name: str, journey, recon, result, truth: dict) -> list[SignPoseError]:
    """One SignPoseError per placed sign of ``result`` matched to a true sign and seen in at
    least two frames that have an estimated pose and a true observation."""
    frame_ids = [f.frame_id for f in journey.frames]
    T_true = {f["frame"]: np.asarray(f["T_world_cam"], float) for f in truth["frames"]}
    T_est = dict(zip(result.trajectory_frame_ids, result.trajectory_T_world_cam))
    c_est = dict(zip(result.trajectory_frame_ids,
                     result_to_truth_enu(result, result.trajectory_enu, truth)))
    xyz_gps = {f: recon.xyz_gps[i] for i, f in enumerate(frame_ids)}
    camera = recon.calib.camera
    kind = gps_kind(truth.get("corpus", {}))
    out = []
    for sign, true_sign in match_signs(result, truth)[0]:
        px = {frame_ids[i]: q for t in recon.tracks if t.track_id == sign.track_id
              for i, q in zip(t.frame_idx, t.px)}
        p_true = {o["frame"]: np.array([o["x"], o["y"], o["z"]])
                  for o in true_sign["observations"]}
        frames = [o.frame_id for o in sign.observations
                  if o.frame_id in p_true and o.frame_id in px and o.frame_id in T_est]
        if len(frames) < 2:
            continue
        placed = np.mean([np.linalg.norm(np.subtract(o.p_cam, p_true[o.frame_id]))
                          for o in sign.observations if o.frame_id in p_true])
        uv = undistort_pixels(camera, np.stack([px[f] for f in frames]))
        p_cam_true = np.stack([p_true[f] for f in frames])
        R_true = np.stack([T_true[f][:3, :3] for f in frames])
        c_true = np.stack([T_true[f][:3, 3] for f in frames])
        R_est = np.stack([T_est[f][:3, :3] for f in frames])
        # The mean rotation offset is the window's heading error: it turns every camera alike.
        offset = Rotation.from_matrix(np.einsum("nij,nkj->nik", R_true, R_est)).mean()
        R_est = np.einsum("ij,njk->nik", offset.as_matrix(), R_est)
        c_sign = np.stack([c_est[f] for f in frames])
        seen = [f for f in px if f in p_true and f in T_true]
        rel = {"placed": float(placed),
               "true poses": _rel_m(_poses(R_true, c_true), uv, camera.K, p_cam_true),
               "true poses, every frame": _rel_m(
                   np.stack([T_true[f] for f in seen]),
                   undistort_pixels(camera, np.stack([px[f] for f in seen])), camera.K,
                   np.stack([p_true[f] for f in seen])),
               "est. rotations": _rel_m(_poses(R_est, c_true), uv, camera.K, p_cam_true),
               "est. centres": _rel_m(_poses(R_true, c_sign), uv, camera.K, p_cam_true)}
        turn_true = Rotation.from_matrix(R_true[0].T @ R_true[-1])
        turn_est = Rotation.from_matrix(R_est[0].T @ R_est[-1])
        d_true = float(np.linalg.norm(c_true[-1] - c_true[0]))
        scale = (lambda a, b: float(np.linalg.norm(b - a)) / d_true - 1.0) if d_true > 1.0 \
            else (lambda a, b: float("nan"))
        out.append(SignPoseError(
            name, sign.track_id, kind, rel,
            float(np.degrees((turn_true * turn_est.inv()).magnitude())),
            scale(c_sign[0], c_sign[-1]), scale(xyz_gps[frames[0]], xyz_gps[frames[-1]])))
    return out


def collect(replay_dir: Path, corpus_dir: Path) -> list[SignPoseError]:
    """Every kept journey of ``replay_dir`` georeferenced again with its own knobs."""
    rows: list[SignPoseError] = []
    for path in sorted(Path(replay_dir).glob("*.pkl")):
        kept = replay.load(path)
        if kept["recon"] is None:
            continue
        truth = json.loads((Path(corpus_dir) / path.stem / "truth.json").read_text())
        try:
            result = georeference(kept["journey"], kept["recon"],
                                  PipelineConfig(**kept["config"]))
        except PipelineError:
            continue
        rows += sign_pose_errors(path.stem, kept["journey"], kept["recon"], result, truth)
    return rows


def table(rows: list[SignPoseError]) -> str:
    """Markdown: per GPS kind, the mean relative error per pose set and the pose errors."""
    head = ("| GPS | signs | " + " | ".join(f"rel mean, {s} (m)" for s in POSE_SETS)
            + " | rotation err median / p90 (deg) | path scale err median / p90 | "
            "GPS scale err median / p90 |")
    lines = [head, "|" + " --- |" * (head.count("|") - 1)]
    for kind in GPS_KINDS:
        rs = [r for r in rows if r.gps == kind]
        if not rs:
            continue
        rel = [f"{np.nanmean([r.rel_m[s] for r in rs]):.3f}" for s in POSE_SETS]

        def spread(values, fmt):
            a = np.abs(np.asarray(values, float))
            a = a[np.isfinite(a)]
            return (f"{fmt(np.median(a))} / {fmt(np.percentile(a, 90))}" if len(a)
                    else "-")
        pct = lambda v: f"{100 * v:.2f} %"  # noqa: E731
        lines.append(f"| {kind} | {len(rs)} | " + " | ".join(rel)
                     + f" | {spread([r.rot_err_deg for r in rs], lambda v: f'{v:.3f}')}"
                     + f" | {spread([r.path_scale_err for r in rs], pct)}"
                     + f" | {spread([r.gps_scale_err for r in rs], pct)} |")
    return "\n".join(lines)

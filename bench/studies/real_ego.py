"""``signmap bench real-ego``: the ego-motion front end on a real drive, against its true poses.

Real imagery (moving cars, exposure, real texture) is what the corpus cannot render, and the real
drives of ``../shared/real/`` (evaluation only: never copied into this repository) have no turn to
self-calibrate on, so they run with their known camera. The pipeline maps only the frames around
sign tracks; here every frame is put on one made-up track so that ego-motion runs over the whole
drive exactly as it would around a sign (same windows, step, front end and knobs).

Reported per ego-motion window, against the true ``T_world_cam`` of the drive (a JSON file with
``frames: [{frame, T_world_cam}]``, as ``kitti0009_poses.json``, or ``T_enu_cam``: one per frame
in order, as ``kitti_turn51_poses.json``):

- the window's registration and reprojection error (the ego_motion stage's report);
- relative rotation error (deg) between frames ``GAP`` mapped frames apart: the angle of
  ``R_rel_est^T R_rel_true``;
- translation direction error (deg): the angle between the estimated and the true motion between
  those frames, in the first one's camera frame;
- scale drift: each step's estimated length over its true length, divided by the window's median
  ratio; the 90th percentile of its deviation from 1 (a window whose scale wanders inside itself
  places signs off along their rays, whatever the GPS says);
- trajectory error: the rms distance of the window's camera centres from the true ones after the
  best similarity between them (its shape, apart from where the GPS puts it).

Without a poses file only the registration is reported.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

GAP = 2  # mapped frames between the two poses of a relative motion (4 journey frames at step 2)


@dataclass(frozen=True)
class WindowFigures:
    frames: tuple[int, int]
    registration: str  # the ego_motion report's line: "k/n registered, e px" or why it failed
    rot_err_deg: np.ndarray  # (P,) per frame pair
    dir_err_deg: np.ndarray  # (P,)
    scale_dev: np.ndarray  # (P,) |step ratio / median - 1|
    trajectory_rms_m: float | None = None  # after a similarity to the true centres


def probe_journey(journey):
    """``journey`` with its detections replaced by one box per frame on one track, so that the
    plan maps every frame."""
    from app.pipeline.types import Detection

    w, h = journey.image_width, journey.image_height
    box = (0.45 * w, 0.45 * h, 0.55 * w, 0.55 * h)
    return replace(journey, detections=[Detection(f.frame_id, "probe", "probe", *box)
                                        for f in journey.frames])


def relative_errors(T_est: np.ndarray, T_true: np.ndarray, gap: int = GAP
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rotation error deg, direction error deg, scale deviation) between poses ``gap`` apart;
    ``T_est`` (K, 4, 4) camera -> model, ``T_true`` (K, 4, 4) camera -> world, same frames."""
    if len(T_est) <= gap:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    rel_est = np.linalg.inv(T_est[:-gap]) @ T_est[gap:]
    rel_true = np.linalg.inv(T_true[:-gap]) @ T_true[gap:]
    R_err = np.einsum("nji,njk->nik", rel_est[:, :3, :3], rel_true[:, :3, :3])
    rot = np.degrees(Rotation.from_matrix(R_err).magnitude())
    t_est, t_true = rel_est[:, :3, 3], rel_true[:, :3, 3]
    n_est, n_true = np.linalg.norm(t_est, axis=1), np.linalg.norm(t_true, axis=1)
    cos = np.einsum("ni,ni->n", t_est, t_true) / np.maximum(n_est * n_true, 1e-12)
    direction = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    ratio = n_est / np.maximum(n_true, 1e-12)
    return rot, direction, np.abs(ratio / np.median(ratio) - 1.0)


def trajectory_rms_m(c_est: np.ndarray, c_true: np.ndarray) -> float:
    """Rms distance (m) of centres ``c_est`` (K, 3, any frame and scale) from ``c_true`` (K, 3)
    after the least-squares similarity between them (Umeyama's scale; Kabsch's rotation, which a
    flat road's planar centres do not trouble)."""
    src, dst = c_est - c_est.mean(0), c_true - c_true.mean(0)
    R = Rotation.align_vectors(dst, src)[0]
    scale = float(np.sum(dst * R.apply(src)) / np.sum(src * src))
    return float(np.sqrt(np.mean(np.sum((scale * R.apply(src) - dst) ** 2, axis=1))))


def true_poses(poses_json: Path, frame_ids: list[str]) -> list[np.ndarray | None]:
    """Each frame's true camera -> world pose, None where the file has none."""
    data = json.loads(poses_json.read_text())
    if "frames" in data:
        by_frame = {f["frame"]: np.asarray(f["T_world_cam"], float) for f in data["frames"]}
        return [by_frame.get(frame_id) for frame_id in frame_ids]
    T = np.asarray(data["T_enu_cam"], float)
    return [T[i] if i < len(T) else None for i in range(len(frame_ids))]


def evaluate(bundle: Path, camera_json: Path, poses_json: Path | None,
             workdir: Path) -> tuple[list[WindowFigures], str]:
    """Ego-motion of ``bundle`` with the camera of ``camera_json``; (figures per window, the
    reconstruction's one-line summary)."""
    from app.commands.process import read_calibration
    from app.pipeline.bundle import read_bundle
    from app.pipeline.run import reconstruct
    from app.pipeline.types import CameraModel
    from bench.corpus.run import pipeline_config

    journey = read_bundle(bundle, workdir / "bundle")
    camera = CameraModel.from_params(journey.image_width, journey.image_height,
                                     read_calibration(str(camera_json)))
    config = pipeline_config({"reuse_known_calibration": True})
    recon = reconstruct(probe_journey(journey), config, workdir / "run", known_camera=camera)
    true = None if poses_json is None else true_poses(poses_json, journey.frame_ids)
    ego = next(r for r in recon.reports if r.stage == "ego_motion")
    lines = dict(d.split(": ", 1) for d in ego.details)
    out = []
    for wp in recon.poses:
        lo, hi = wp.window
        rot = direction = dev = np.zeros(0)
        rms_m = None
        if true is not None:
            keep = np.array([true[i] is not None for i in wp.frame_idx], bool)
            if keep.sum() > GAP:
                T_true = np.stack([true[i] for i in wp.frame_idx[keep]])
                rot, direction, dev = relative_errors(wp.T_model_cam[keep], T_true)
                rms_m = trajectory_rms_m(wp.T_model_cam[keep, :3, 3], T_true[:, :3, 3])
        out.append(WindowFigures((lo, hi), lines.get(f"frames {lo}-{hi - 1}", ""), rot,
                                 direction, dev, rms_m))
    return out, ego.summary


def table(name: str, figures: list[WindowFigures], summary: str) -> str:
    def stat(a: np.ndarray) -> str:
        return "–" if not len(a) else f"{np.median(a):.3f} / {np.percentile(a, 90):.3f}"

    rows = [f"**{name}**: {summary}", "",
            "| window (frames) | registration | rotation error deg median / p90 | "
            "direction error deg median / p90 | scale drift median / p90 | "
            "trajectory rms after a similarity (m) |",
            "| --- | --- | --- | --- | --- | --- |"]
    for f in figures:
        rms = "–" if f.trajectory_rms_m is None else f"{f.trajectory_rms_m:.3f}"
        rows.append(f"| {f.frames[0]}-{f.frames[1] - 1} | {f.registration} | "
                    f"{stat(f.rot_err_deg)} | {stat(f.dir_err_deg)} | {stat(f.scale_dev)} | "
                    f"{rms} |")
    every = [np.concatenate([getattr(f, k) for f in figures] or [np.zeros(0)])
             for k in ("rot_err_deg", "dir_err_deg", "scale_dev")]
    rows.append(f"| all | | {stat(every[0])} | {stat(every[1])} | {stat(every[2])} | |")
    return "\n".join(rows)


def run(bundle: str, camera_json: str, poses_json: str | None) -> str:
    with tempfile.TemporaryDirectory(prefix="signmap-real-ego-") as tmp:
        figures, summary = evaluate(Path(bundle), Path(camera_json),
                                    Path(poses_json) if poses_json else None, Path(tmp))
    return table(Path(bundle).name, figures, summary)

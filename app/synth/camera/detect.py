"""What an on-board sign detector would report: boxes around the visible plates, in the original
(distorted) image, with pixel noise, misses and false detections."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.pipeline.types import CameraModel, Detection
from app.synth.camera.lens import fold_radius
from app.synth.camera.render import first_hits
from app.synth.camera.scene import Scene
from app.synth.street.layout import SIGN_CLASSES
from app.synth.street.world import SignTruth

MIN_RANGE_M = 3.0
MAX_RANGE_M = 40.0
MARGIN_PX = 4.0
MIN_BOX_PX = 8.0
MIN_FACING_COS = 0.2  # the camera must be within ~78 degrees of the plate's normal


@dataclass(frozen=True)
class SignView:
    """A sign seen in one frame: its true box (before noise) and camera-frame position."""

    frame_index: int
    sign_index: int  # index into the journey's sign list
    p_cam: np.ndarray  # (3,) metres
    box_px: np.ndarray  # (4,) x1, y1, x2, y2 of the projected rim, unclipped


def project(camera: CameraModel, p_cam: np.ndarray) -> np.ndarray:
    """Camera-frame points (K, 3) -> distorted pixels (K, 2), OpenCV convention."""
    px, _ = cv2.projectPoints(np.asarray(p_cam, np.float64).reshape(-1, 1, 3), np.zeros(3),
                              np.zeros(3), camera.K, camera.dist)
    return px.reshape(-1, 2)


def _in_model_domain(camera: CameraModel, p_cam: np.ndarray, px: np.ndarray) -> bool:
    """Radial models fold over far off-axis; a projection counts only if undistorting gives the
    ray back."""
    und = cv2.undistortPoints(px.reshape(-1, 1, 2), camera.K, camera.dist,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                        100, 1e-10))
    if np.allclose(und.reshape(-1, 2), p_cam[:, :2] / p_cam[:, 2:3], atol=1e-6):
        return True
    # OpenCV's iteration may stop short on a wide-angle lens where the model is one-to-one.
    r_u = np.hypot(p_cam[:, 0], p_cam[:, 1]) / p_cam[:, 2]
    return bool(np.all(r_u < fold_radius(camera.k1, camera.k2)))


def visible_signs(camera: CameraModel, scene: Scene, signs: list[SignTruth], plate_ids: list[int],
                  T_world_cam: np.ndarray) -> list[SignView]:
    """Every (frame, sign) whose plate centre is 3..40 m ahead, inside the image and unoccluded,
    with the camera in front of the plate."""
    views = []
    w, h = camera.width, camera.height
    for f, T in enumerate(T_world_cam):
        R_world_cam, c_world = T[:3, :3], T[:3, 3]
        for k, sign in enumerate(signs):
            p_cam = R_world_cam.T @ (sign.centre_enu - c_world)
            dist = float(np.linalg.norm(p_cam))
            if p_cam[2] <= 0 or not MIN_RANGE_M <= dist <= MAX_RANGE_M:
                continue
            # A detector recognises a plate's face, not its back or a nearly edge-on view.
            if float(sign.normal_enu @ (c_world - sign.centre_enu)) < MIN_FACING_COS * dist:
                continue
            centre_px = project(camera, p_cam[None])[0]
            if not (MARGIN_PX <= centre_px[0] <= w - 1 - MARGIN_PX
                    and MARGIN_PX <= centre_px[1] <= h - 1 - MARGIN_PX):
                continue
            if not _in_model_domain(camera, p_cam[None], centre_px):
                continue
            t, ids = first_hits(scene, c_world, (sign.centre_enu - c_world)[None],
                                ignore_ground=True)
            if ids[0] != plate_ids[k] and t[0] < 1.0 - 1e-6:
                continue
            rim_cam = (sign.outline_enu() - c_world) @ R_world_cam
            rim_px = project(camera, rim_cam)
            box = np.concatenate([rim_px.min(axis=0), rim_px.max(axis=0)])
            views.append(SignView(frame_index=f, sign_index=k, p_cam=p_cam, box_px=box))
    return views


def noisy_detections(rng: np.random.Generator, camera: CameraModel, views: list[SignView],
                     signs: list[SignTruth], frame_ids: list[str], track_ids: list[str],
                     noise_px: float) -> tuple[list[Detection], list[SignView]]:
    """Detections with Gaussian corner noise, clipped to the image; boxes under MIN_BOX_PX on a
    side are dropped. Returns the detections and the views they came from."""
    dets, kept = [], []
    for view in views:
        box = view.box_px + noise_px * rng.standard_normal(4)
        score = float(rng.uniform(0.6, 0.99))
        box[[0, 2]] = np.clip(box[[0, 2]], 0, camera.width - 1)
        box[[1, 3]] = np.clip(box[[1, 3]], 0, camera.height - 1)
        if box[2] - box[0] < MIN_BOX_PX or box[3] - box[1] < MIN_BOX_PX:
            continue
        sign = signs[view.sign_index]
        dets.append(Detection(frame_id=frame_ids[view.frame_index],
                              track_id=track_ids[view.sign_index], cls=sign.cls,
                              x1=float(box[0]), y1=float(box[1]), x2=float(box[2]),
                              y2=float(box[3]), score=round(score, 3)))
        kept.append(view)
    return dets, kept


def drop_missed(rng: np.random.Generator, dets: list[Detection], views: list[SignView],
                miss_rate: float) -> tuple[list[Detection], list[SignView], list[Detection]]:
    """A detector that misses each plate with probability ``miss_rate`` per frame; returns the
    kept detections, their views and the missed detections."""
    if miss_rate <= 0.0 or not dets:
        return dets, views, []
    missed = rng.random(len(dets)) < miss_rate
    kept = [i for i in range(len(dets)) if not missed[i]]
    return ([dets[i] for i in kept], [views[i] for i in kept],
            [d for d, m in zip(dets, missed) if m])


def false_tracks(rng: np.random.Generator, camera: CameraModel, n_tracks: int,
                 frame_ids: list[str], first_track_id: int, blank_ids: bool) -> list[Detection]:
    """``n_tracks`` short tracks (2-6 frames) of boxes where there is no sign, with a real sign
    class: what a detector hallucinates on a poster or a tail light. Each box drifts and grows a
    little from frame to frame, as a real detection of something static would."""
    dets = []
    w, h = camera.width, camera.height
    for k in range(n_tracks):
        length = int(rng.integers(2, 7))
        first = int(rng.integers(0, max(1, len(frame_ids) - length + 1)))
        size = max(MIN_BOX_PX + 4.0, float(rng.uniform(0.01, 0.04)) * w)
        x, y = float(rng.uniform(0, w - size)), float(rng.uniform(0, h - size))
        vx, vy = rng.uniform(-0.01, 0.01, 2) * w
        cls = str(rng.choice(SIGN_CLASSES))
        tid = "" if blank_ids else str(first_track_id + k)
        for f in range(first, min(first + length, len(frame_ids))):
            box = np.clip([x, y, x + size, y + size], 0, [w - 1, h - 1, w - 1, h - 1])
            if box[2] - box[0] >= MIN_BOX_PX and box[3] - box[1] >= MIN_BOX_PX:
                dets.append(Detection(frame_id=frame_ids[f], track_id=tid, cls=cls,
                                      x1=float(box[0]), y1=float(box[1]), x2=float(box[2]),
                                      y2=float(box[3]),
                                      score=round(float(rng.uniform(0.4, 0.9)), 3)))
            x, y, size = x + vx, y + vy, size * 1.04
    return dets

"""Calibrated turn windows made without COLMAP's mapper: what a joint calibration adjusts
(``cameras.calibrate_jointly``), for tests of it and of the service that keeps them."""

from __future__ import annotations

import cv2
import numpy as np

from app.pipeline.types import CameraModel, WindowObservations


def turn_window(camera: CameraModel, seed: int, noise_px: float = 0.3,
            turn_deg: float = 70.0) -> WindowObservations:
    """A calibrated window as ``sfm.window_observations`` gives it, made by projecting points
    through ``camera`` (``noise_px`` of noise): 16 frames driving a left turn of ``turn_deg`` on
    a 15 m radius (world z up), a few hundred points 4-30 m off the road, kept where at least
    three frames see them inside the image. The poses and points are the true ones."""
    rng = np.random.default_rng(seed)
    yaw = np.radians(np.linspace(0.0, turn_deg, 16))
    R0 = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # cam z forward = world +y, y down
    T_cam_world = []
    for a in yaw:
        centre = np.array([-15.0 * (1 - np.cos(a)), 15.0 * np.sin(a), 1.5])
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
        R_world_cam = Rz @ R0.T
        T = np.eye(4)
        T[:3, :3] = R_world_cam.T
        T[:3, 3] = -R_world_cam.T @ centre
        T_cam_world.append(T)
    ang = rng.uniform(-0.3, np.radians(turn_deg) + 0.6, 900)
    radius = 15.0 + rng.choice([-1, 1], 900) * rng.uniform(4.0, 30.0, 900)
    xyz = np.c_[-15.0 + radius * np.cos(ang), radius * np.sin(ang), rng.uniform(0.0, 8.0, 900)]
    xy, obs_image, obs_point = [], [], []
    for k, T in enumerate(T_cam_world):
        p_cam = xyz @ T[:3, :3].T + T[:3, 3]
        front = p_cam[:, 2] > 1.0
        uv, _ = cv2.projectPoints(p_cam[front], np.zeros(3), np.zeros(3), camera.K,
                                  camera.dist)
        uv = uv.reshape(-1, 2) + rng.normal(0.0, noise_px, (int(front.sum()), 2))
        inside = (uv[:, 0] > 0) & (uv[:, 0] < camera.width - 1) & (uv[:, 1] > 0) & (
            uv[:, 1] < camera.height - 1)
        xy.append(uv[inside])
        obs_image += [k] * int(inside.sum())
        obs_point += list(np.flatnonzero(front)[inside])
    seen, counts = np.unique(obs_point, return_counts=True)
    keep = set(seen[counts >= 3])
    rows = np.array([p in keep for p in obs_point])
    index = {p: i for i, p in enumerate(sorted(keep))}
    return WindowObservations(f"w{seed}", np.array(T_cam_world), xyz[sorted(keep)],
                              np.concatenate(xy)[rows], np.array(obs_image)[rows],
                              np.array([index[p] for p in np.array(obs_point)[rows]]))

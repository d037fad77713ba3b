"""The camera's path along the road and the noisy GPS a cheap receiver would log on it."""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from app.synth.street.road import Road


def smooth_noise(rng: np.random.Generator, n: int, sigma_samples: float,
                 dims: int = 1) -> np.ndarray:
    """Gaussian-smoothed white noise of unit standard deviation, shape (n, dims)."""
    if sigma_samples <= 0:
        return rng.standard_normal((n, dims))
    pad = int(math.ceil(4.0 * sigma_samples))  # so short sequences see a full kernel of noise
    white = rng.standard_normal((n + 2 * pad, dims))
    # A unit-sum Gaussian of width sigma leaves white noise with std 1/sqrt(2 sqrt(pi) sigma).
    gain = math.sqrt(2.0 * math.sqrt(math.pi) * sigma_samples)
    return gaussian_filter1d(white, sigma_samples, axis=0)[pad:pad + n] * gain


def camera_poses(road: Road, s_m: np.ndarray, lateral_m: float, cam_height_m: float,
                 pitch_rad: np.ndarray, roll_rad: np.ndarray,
                 heading_sigma_m: float = 2.0) -> np.ndarray:
    """T_world_cam (N, 4, 4) of a camera driving the lane ``lateral_m`` right of the centreline.

    The camera looks along the road's tangent, averaged over a few metres so its heading changes
    continuously into and out of arcs (a road's curvature jumps there, a car's yaw rate does not).
    """
    offsets = np.linspace(-3.0, 3.0, 25) * heading_sigma_m
    weights = np.exp(-0.5 * (offsets / heading_sigma_m) ** 2)
    _, h = road.at((s_m[:, None] + offsets[None, :]).ravel())
    heading = (h.reshape(len(s_m), -1) * weights).sum(axis=1) / weights.sum()
    xy = road.offset(s_m, np.full(len(s_m), lateral_m))
    forward = np.column_stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)])
    right = np.column_stack([np.sin(heading), -np.cos(heading), np.zeros_like(heading)])
    down = np.tile([0.0, 0.0, -1.0], (len(s_m), 1))
    R_world_base = np.stack([right, down, forward], axis=2)  # columns: camera x, y, z
    # Pitch turns about the camera's x axis, roll about its z axis.
    R_base_cam = Rotation.from_euler("XZ", np.column_stack([pitch_rad, roll_rad])).as_matrix()
    T = np.tile(np.eye(4), (len(s_m), 1, 1))
    T[:, :3, :3] = R_world_base @ R_base_cam
    T[:, :3, 3] = np.column_stack([xy, np.full(len(s_m), cam_height_m)])
    return T


def noisy_gps(rng: np.random.Generator, xyz_enu: np.ndarray, fps: float, white_sigma_m: float,
              bias_sigma_m: float, bias_m: tuple[float, float, float], alt_sigma_m: float,
              bias_time_s: float = 4.0) -> np.ndarray:
    """GPS fixes (N, 3) ENU: truth + white noise + a slowly wandering horizontal bias + a constant
    bias; altitude gets its own (larger) white noise."""
    n = len(xyz_enu)
    noise = np.zeros((n, 3))
    noise[:, :2] = white_sigma_m * rng.standard_normal((n, 2))
    noise[:, :2] += bias_sigma_m * smooth_noise(rng, n, bias_time_s * fps, dims=2)
    noise[:, 2] = alt_sigma_m * rng.standard_normal(n)
    return xyz_enu + noise + np.asarray(bias_m, float)


def fix_times(duration_s: float, rate_hz: float, phase_s: float,
              dropouts: tuple[tuple[float, float], ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """A receiver's clock: fixes every 1/rate_hz from ``phase_s`` after the first frame up to the
    last frame (so the first fix comes after the first frame and the last before the last one).
    Returns the full grid and a mask of the fixes kept outside the (start_s, length_s) dropouts."""
    t = phase_s + np.arange(int(math.floor((duration_s - phase_s) * rate_hz + 1e-9)) + 1) / rate_hz
    keep = np.ones(len(t), bool)
    for start_s, length_s in dropouts:
        keep &= ~((t >= start_s) & (t < start_s + length_s))
    return t, keep

"""What a real camera adds to the exact render: motion blur during the exposure, auto-exposure
drift and jumps, and sensor noise. Seeded per journey and frame; all off by default, and then
``apply`` is never called, so default frames stay the renderer's pixels.

JPEG compression, the last effect, is the bundle writer's (``jpeg_quality``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from app.synth.camera.render import CameraRays, Rendered
from app.synth.drive.trajectory import smooth_noise

MAX_BLUR_PX = 8.0  # a pixel's blur streak is clipped here (the ground right beside the car)
MAX_BLUR_SAMPLES = 9
GAIN_CORRELATION_S = 3.0  # auto-exposure drifts over seconds
GAIN_RECOVERY_S = 2.0  # after a jump, auto-exposure settles back over seconds
GAIN_RANGE = (0.5, 1.8)


@dataclass(frozen=True)
class ImageEffects:
    exposure_s: float  # 0: no motion blur
    gain: np.ndarray  # (N,) brightness factor per frame
    noise_dn: float  # sensor noise std in 8-bit digital numbers
    seed: tuple[int, ...]  # with the frame index: the frame's noise stream

    @property
    def active(self) -> bool:
        return self.exposure_s > 0 or self.noise_dn > 0 or bool(np.any(self.gain != 1.0))

    def apply(self, i: int, rendered: Rendered, rays: CameraRays, T_world_cam: np.ndarray,
              timestamps_s: np.ndarray) -> np.ndarray:
        img = rendered.image_bgr.astype(np.float32)
        if self.exposure_s > 0 and len(timestamps_s) > 1:
            a, b = max(i - 1, 0), min(i + 1, len(timestamps_s) - 1)
            fraction = self.exposure_s / float(timestamps_s[b] - timestamps_s[a])
            img = motion_blur(img, rendered.depth_m, rays,
                              np.linalg.inv(T_world_cam[a]) @ T_world_cam[b], fraction)
        img *= np.float32(self.gain[i])
        if self.noise_dn > 0:
            rng = np.random.default_rng([*self.seed, i])
            img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(self.noise_dn)
        return np.clip(np.round(img), 0, 255).astype(np.uint8)


def image_effects(rng: np.random.Generator, seed: tuple[int, ...], n_frames: int, fps: float,
                  exposure_s: float, gain_drift: float, gain_jump_rate_hz: float,
                  noise_dn: float) -> ImageEffects:
    """Per-frame gains: exp(``gain_drift`` x smooth noise) times jumps of +-10..30 % (a Poisson
    process of ``gain_jump_rate_hz``) that auto-exposure then corrects over GAIN_RECOVERY_S."""
    log_gain = np.zeros(n_frames)
    if gain_drift > 0:
        log_gain += gain_drift * smooth_noise(rng, n_frames, GAIN_CORRELATION_S * fps)[:, 0]
    if gain_jump_rate_hz > 0:
        jumps = rng.random(n_frames) < gain_jump_rate_hz / fps
        sizes = np.log1p(rng.choice([-1.0, 1.0], n_frames) * rng.uniform(0.1, 0.3, n_frames))
        decay = math.exp(-1.0 / (GAIN_RECOVERY_S * fps))
        level = 0.0
        for k in range(n_frames):
            level = level * decay + (sizes[k] if jumps[k] else 0.0)
            log_gain[k] += level
    gain = np.clip(np.exp(log_gain), *GAIN_RANGE)
    return ImageEffects(exposure_s=exposure_s, gain=gain, noise_dn=noise_dn, seed=seed)


def motion_blur(img: np.ndarray, depth_m: np.ndarray, rays: CameraRays, T_a_b: np.ndarray,
                fraction: float) -> np.ndarray:
    """Average ``img`` along each pixel's image motion during the exposure: the camera moves by
    ``fraction`` of ``T_a_b`` (the pose of a later camera in an earlier one's frame), centred on
    this frame. The motion comes from the true depth, so near things smear more than far ones."""
    cam = rays.camera
    rotvec = Rotation.from_matrix(T_a_b[:3, :3]).as_rotvec()
    ends = []
    for h in (-0.5 * fraction, 0.5 * fraction):
        R = Rotation.from_rotvec(h * rotvec).as_matrix().astype(np.float32)
        t = (h * T_a_b[:3, 3]).astype(np.float32)
        finite = np.isfinite(depth_m)
        z = np.where(finite, depth_m, np.float32(1.0))
        p = [rays.xn * z, rays.yn * z, z]
        # Far points (the sky) only turn with the camera; near ones also slide past it.
        p = [p[k] - np.where(finite, t[k], np.float32(0.0)) for k in range(3)]
        q = [R[0, k] * p[0] + R[1, k] * p[1] + R[2, k] * p[2] for k in range(3)]  # R^T p
        zq = np.maximum(q[2], np.float32(0.05))
        ends.append((q[0] / zq * np.float32(cam.fx), q[1] / zq * np.float32(cam.fy)))
    du, dv = ends[1][0] - ends[0][0], ends[1][1] - ends[0][1]
    length = np.hypot(du, dv)
    shrink = np.minimum(np.float32(1.0), np.float32(MAX_BLUR_PX) / np.maximum(length, 1e-6))
    du, dv = du * shrink, dv * shrink
    longest = float(np.percentile(length, 99.5))
    if longest < 0.5:
        return img
    n = int(min(MAX_BLUR_SAMPLES, max(2, math.ceil(min(longest, MAX_BLUR_PX)) + 1)))
    h, w = img.shape[:2]
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    out = np.zeros_like(img)
    for k in range(n):
        off = np.float32(k / (n - 1) - 0.5)
        out += cv2.remap(img, cols + off * du, rows + off * dv, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)
    return out / np.float32(n)

"""The plan's last look for a turn, on the images, where the GPS track shows none.

A journey of a few seconds with phone-grade fixes can turn 60-90 deg where its GPS track, 14-45 m
long and scattered by metres, shows no corner at all (tuning journeys c0224, c0414, c0470, c0492,
c0504 of corpus seeds 192-448: 25-30 frames/s, 10-12 s, the turn often at one end). The camera
sees the turn whatever the GPS does, so before such a journey is refused "no turn" its frames are
asked.

Every few frames (``sample_frames``) are scaled down and corners followed through them (KLT,
``colmap.klt_features.track_features``); a car's planar motion (a turn about the camera's vertical
axis, a step along the arc's chord) is fitted to each pair of consecutive sampled frames
(``planar_yaw_deg``) and its turn is the heading change (``heading_deg``). The focal length is not
known yet: the calibration's first guess stands in, and an angle read through a focal length a
times too long comes out about 1/a times too small (a wide lens reads its turns short, a narrow
one long). The largest heading change over a stretch of road is the journey's turn
(``strongest_turn``), around which the plan builds its candidate windows as for a turn of the GPS
track; each is only a candidate: calibration judges it as any other (rotation, registration, the
GPS rotation check).

Pixels are OpenCV's; the camera frame is x right, y down, z forward (``types``). Headings are
degrees, left (counter-clockwise seen from above) positive, as in ``turns``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.pipeline.colmap.klt_features import KltOptions, track_features
from app.pipeline.steps.turns import TurnWindow

# Corners followed on the small frames: fewer and closer than ego-motion's, for speed.
_KLT = KltOptions(max_corners=400, min_distance_px=8)
_MIN_MATCHES = 12  # fewer shared corners than this: the pair says nothing


@dataclass(frozen=True)
class ImageHeadings:
    """``frame_idx`` (M,) the sampled journey frames; ``heading_deg`` (M,) the camera's heading
    at each relative to the first (left positive); ``unmeasured`` how many of the M - 1 pairs
    could not be measured (taken as not turning)."""

    frame_idx: np.ndarray
    heading_deg: np.ndarray
    unmeasured: int


def sample_frames(timestamp_s: np.ndarray, interval_s: float, max_frames: int) -> np.ndarray:
    """(M,) frame indices about ``interval_s`` apart in time (at least one frame apart), the
    last frame included; at most ``max_frames`` of them (then evenly spread)."""
    t = np.asarray(timestamp_s, dtype=float)
    n = len(t)
    if n < 2:
        return np.arange(n)
    frame_s = float(np.median(np.diff(t)))
    step = max(1, int(round(interval_s / max(frame_s, 1e-9))), int(np.ceil((n - 1) / max(
        max_frames - 1, 1))))
    return np.unique(np.r_[np.arange(0, n, step), n - 1])


def heading_deg(images: list[np.ndarray], focal_px: float, frame_idx: np.ndarray, *,
                min_flow_px: float = 0.5, inlier_px: float = 1.0) -> ImageHeadings:
    """Headings of the camera at ``images`` (8-bit grayscale, one size, principal point taken at
    the centre), the journey frames ``frame_idx`` (M,), through a pinhole of ``focal_px``.

    A pair whose corners barely move (median flow under ``min_flow_px``: the car stands) turns
    nothing: its geometry is noise."""
    h, w = images[0].shape[:2]
    centre = np.array([(w - 1) / 2, (h - 1) / 2])
    tracks = track_features(images, _KLT)
    change = np.zeros(len(images))
    unmeasured = 0
    for k in range(1, len(images)):
        pairs = tracks.pair_matches(k - 1, k)
        if len(pairs) < _MIN_MATCHES:
            unmeasured += 1
            continue
        p0 = tracks.keypoints_px[k - 1][pairs[:, 0]].astype(np.float64)
        p1 = tracks.keypoints_px[k][pairs[:, 1]].astype(np.float64)
        if np.median(np.linalg.norm(p1 - p0, axis=1)) < min_flow_px:
            continue
        change[k] = planar_yaw_deg((p0 - centre) / focal_px, (p1 - centre) / focal_px,
                                   inlier_px / focal_px)
    return ImageHeadings(np.asarray(frame_idx), np.cumsum(change), unmeasured)


def planar_yaw_deg(x0: np.ndarray, x1: np.ndarray, inlier: float, *,
                   max_deg: float = 30.0) -> float:
    """Heading change (degrees, left positive) between two views of a car's camera, from the
    normalised image points ``x0``, ``x1`` (K, 2) of the same corners: the yaw whose planar
    motion model best explains them (MSAC: squared Sampson errors capped at ``inlier``^2).

    The model is a car's: over a fraction of a second it drives a circular arc, so the camera
    turns by psi about its vertical axis and moves along the arc's chord, psi / 2 off its
    forward axis. One parameter, searched on a grid and refined, where OpenCV's five-point
    essential matrix has five: on a wide crop through a strong lens (k1 -0.37) those traded the
    turn for sideways motion and read a 180 deg U-turn as 99 deg (this model: 163), and they
    drifted 4 deg on 10 s of straight road (this model: 0). A camera mounted askew breaks the
    model's assumption that the chord lies about the optical axis."""
    def cost(psi: np.ndarray) -> np.ndarray:
        c, s = np.cos(psi), np.sin(psi)
        zero, one = np.zeros_like(psi), np.ones_like(psi)
        R_1_0 = np.stack([np.stack([c, zero, -s], -1), np.stack([zero, one, zero], -1),
                          np.stack([s, zero, c], -1)], -2)  # frame 0 into frame 1: Ry(-psi)
        t_1_0 = np.stack([np.sin(psi / 2), zero, -np.cos(psi / 2)], -1)
        E = np.cross(t_1_0[:, None, :], np.swapaxes(R_1_0, 1, 2)).swapaxes(1, 2)  # [t]x R
        h0 = np.c_[x0, np.ones(len(x0))]
        h1 = np.c_[x1, np.ones(len(x1))]
        line1 = h0 @ np.swapaxes(E, 1, 2)  # (G, K, 3): epipolar lines in view 1
        line0 = h1 @ E
        r = np.sum(line1 * h1, axis=-1)
        sampson = r**2 / (line1[..., 0]**2 + line1[..., 1]**2 + line0[..., 0]**2
                          + line0[..., 1]**2 + 1e-30)
        return np.minimum(sampson, inlier**2).sum(axis=1)

    coarse = np.radians(np.arange(-max_deg, max_deg + 1e-9, 0.5))
    best = coarse[np.argmin(cost(coarse))]
    fine = best + np.radians(np.arange(-0.5, 0.5 + 1e-9, 0.02))
    # psi turns the camera's forward axis towards +x (right): a negative heading change.
    return -float(np.degrees(fine[np.argmin(cost(fine))]))


def strongest_turn(s_m: np.ndarray, headings: ImageHeadings, *, window_m: float,
                   min_angle_deg: float) -> TurnWindow | None:
    """The images' largest heading change over at most ``window_m`` of road, as the plan's turn
    (``turns.TurnWindow``; None if under ``min_angle_deg``); ``s_m`` (N,): metres travelled at
    each journey frame (``turns.track_length_m`` of the GPS track).

    Taken on the headings themselves, not by RDP on a track drawn from them: these journeys are
    short (14-31 m of track for tuning c0224, c0414, c0470, c0504), their turn often at one end,
    where a polyline has no corner. The curve is where the heading goes from a tenth to nine
    tenths of the change, its vertex where it is half done; the window reaches ``window_m``
    beyond the curve either way, as ``turns.find_turns``'s do."""
    s_m = np.asarray(s_m, dtype=float)
    idx, h = headings.frame_idx, headings.heading_deg
    if len(idx) < 2:
        return None
    at_m = s_m[idx]
    reach = at_m[None, :] - at_m[:, None]
    change = np.where((reach >= 0) & (reach <= window_m), h[None, :] - h[:, None], 0.0)
    a, b = np.unravel_index(np.argmax(np.abs(change)), change.shape)
    angle = float(change[a, b])
    if abs(angle) < min_angle_deg:
        return None
    done = (h[a:b + 1] - h[a]) / angle  # share of the turn done at each sample from a to b
    first = a + int(np.argmax(done >= 0.1))
    last = a + int(np.flatnonzero(done <= 0.9)[-1])
    vertex = int(idx[a + int(np.argmax(done >= 0.5))])
    start = int(np.searchsorted(s_m, at_m[first] - window_m, side="left"))
    end = int(np.searchsorted(s_m, at_m[last] + window_m, side="right"))
    rotation = float(np.sum(np.abs(np.diff(h[a:b + 1]))))
    return TurnWindow(start, min(end, len(s_m)), vertex, angle, rotation,
                      float(at_m[last] - at_m[first]))


def rotation_deg(n_frames: int, headings: ImageHeadings) -> np.ndarray:
    """(N,) degrees the images turn, whatever the direction, up to each of the journey's
    ``n_frames`` frames (interpolated between the sampled ones): ``calibrate.candidate_windows``
    spreads a window's images by it."""
    turned = np.r_[0.0, np.cumsum(np.abs(np.diff(headings.heading_deg)))]
    return np.interp(np.arange(n_frames), headings.frame_idx, turned)


def scaled_to(image: np.ndarray, width_px: int) -> np.ndarray:
    """``image`` scaled down (area averaging) to at most ``width_px`` wide."""
    h, w = image.shape[:2]
    if w <= width_px:
        return image
    return cv2.resize(image, (width_px, max(1, round(h * width_px / w))),
                      interpolation=cv2.INTER_AREA)

"""The parts of a corpus journey draw (``app.synth.draw``, this package). Each takes the journey's generator,
records what it drew in ``params`` (flat, JSON-able) and returns what ``SynthConfig`` needs."""

from __future__ import annotations

import math

import numpy as np

from app.pipeline.types import CameraModel
from app.synth.camera.lens import camera_from_fov, corner_radius_u

ASPECTS = {"4:3": (4 / 3, 640, 1440), "16:9": (16 / 9, 640, 1920), "wide": (3.3, 1000, 1920)}
K2_RESAMPLES = 8  # a folding lens first gets new k2 draws, then a narrower field of view
FOV_SHRINK_DEG = 5.0
REF_DEPTH_M = 8.0  # the blur length is set for a point this far away at 45 degrees
GPS_RATES_HZ = (1.0, 2.0, 4.0, 5.0, 10.0)


def _turns_label(specs) -> str:
    return " ".join(f"{a:+.0f}@{r:.0f}" for a, r in specs)


def draw_road(rng, params: dict) -> dict:
    """~70 % real turns (single, double, roundabout, U-turn), ~15 % gentle bends, ~15 % sharp city
    corners. Angles are signed degrees (positive left), radii metres."""
    u = rng.random()
    side = lambda: 1.0 if rng.random() < 0.5 else -1.0  # noqa: E731
    radius = lambda lo, hi: float(np.exp(rng.uniform(math.log(lo), math.log(hi))))  # noqa: E731
    sub = ""
    if u < 0.70:
        kind = "turns"
        sub = str(rng.choice(["single", "double", "roundabout", "uturn"], p=[.45, .25, .15, .15]))
        if sub == "single":
            specs, gaps = [(side() * rng.uniform(30, 180), radius(5, 60))], []
        elif sub == "double":
            specs = [(side() * rng.uniform(30, 150), radius(5, 60)) for _ in range(2)]
            gaps = [rng.uniform(15, 60)]
        elif sub == "roundabout":  # right onto the circle, around it to the left, right out
            mirror, entry_r = side(), rng.uniform(8, 12)
            specs = [(-mirror * rng.uniform(30, 45), entry_r),
                     (mirror * rng.uniform(120, 250), rng.uniform(10, 20)),
                     (-mirror * rng.uniform(30, 45), entry_r)]
            gaps = [0.0, 0.0]
        else:
            specs, gaps = [(side() * 180.0, rng.uniform(5, 8))], []
    elif u < 0.85:
        kind = "gentle"
        n = int(rng.integers(2, 5))
        specs = [(side() * rng.uniform(5, 20), rng.uniform(60, 200)) for _ in range(n)]
        gaps = list(rng.uniform(15, 40, n - 1))  # > the yaw smoothing: bends stay apart
    else:
        kind = "city"
        n = int(rng.integers(1, 3))
        specs = [(side() * rng.uniform(80, 100), rng.uniform(6, 15)) for _ in range(n)]
        gaps = list(rng.uniform(20, 50, n - 1))
    specs = tuple((round(float(a), 2), round(float(r), 2)) for a, r in specs)
    gaps = tuple(round(float(g), 2) for g in gaps)
    params.update({"kind": kind, "turn_kind": sub or kind, "turns": _turns_label(specs),
                   "n_turns": len(specs), "planned_rotation_deg":
                   round(sum(abs(a) for a, _ in specs), 2),
                   "min_radius_m": min(r for _, r in specs)})
    return {"turn_specs": specs, "gaps": gaps}


def _resolution(rng) -> tuple[str, int, int]:
    aspect = str(rng.choice(list(ASPECTS), p=[0.3, 0.45, 0.25]))
    ratio, lo, hi = ASPECTS[aspect]
    width = 2 * int(rng.integers(lo // 2, hi // 2 + 1))
    return aspect, width, 2 * int(round(width / ratio / 2))


def draw_camera(rng, params: dict) -> CameraModel:
    """Resolution, field of view, lens and principal point. A lens that folds over (or nearly)
    inside the image corners gets new k2 draws, then a field of view FOV_SHRINK_DEG narrower."""
    aspect, width, height = _resolution(rng)
    hfov = float(rng.uniform(45.0, 110.0))
    k1 = float(rng.uniform(-0.45, 0.10))
    cx_off, cy_off = (float(rng.uniform(-0.03, 0.03)) for _ in range(2))
    fy_ratio = 1.0 + float(rng.uniform(-0.005, 0.005))
    drawn_hfov, resamples = hfov, 0
    while True:
        k2 = float(rng.uniform(-0.05, 0.25))
        cam = camera_from_fov(width, height, hfov, k1, k2, cx_off, cy_off, fy_ratio)
        if cam is not None:
            break
        resamples += 1
        if resamples % K2_RESAMPLES == 0:
            hfov -= FOV_SHRINK_DEG
            if hfov < 20.0:  # cannot happen for the drawn k1 range; never loop forever
                raise RuntimeError(f"no usable lens for k1 = {k1}")
    params.update({
        "aspect": aspect, "width": width, "height": height, "hfov_deg": round(hfov, 2),
        "hfov_drawn_deg": round(drawn_hfov, 2), "lens_resamples": resamples,
        "corner_fov_deg": round(2 * math.degrees(math.atan(corner_radius_u(cam))), 2),
        "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "k1": k1, "k2": k2})
    return cam


def draw_scene(rng, params: dict) -> dict:
    density = round(float(rng.uniform(0.0, 1.0)), 3)
    repeated = bool(rng.random() < 0.25)
    low = bool(rng.random() < 0.15)
    label = "sparse" if density < 1 / 3 else ("mixed" if density < 2 / 3 else "dense")
    params.update({"scene": label, "scene_density": density, "repeated_facades": repeated,
                   "low_texture": low})
    return {"scene_density": density, "repeated_facades": repeated, "low_texture": low}


def draw_effects(rng, params: dict, camera: CameraModel, speed_mps: float, fps: float) -> dict:
    """Blur 0..6 px (as an exposure time: the streak of a point REF_DEPTH_M away at 45 degrees
    at cruise speed), exposure drift and jumps, sensor noise, JPEG 60..95 or PNG."""
    blur_px = 0.0 if rng.random() < 0.3 else float(rng.uniform(0.5, 6.0))
    exposure_s = min(blur_px * REF_DEPTH_M / (camera.fx * speed_mps), 0.5 / fps, 1 / 30)
    gain_drift = float(rng.uniform(0.0, 0.1))
    jumps_hz = float(rng.uniform(0.02, 0.1)) if rng.random() < 0.3 else 0.0
    noise_dn = float(rng.uniform(0.0, 4.0))
    png = bool(rng.random() < 0.2)
    quality = 95 if png else int(rng.integers(60, 96))
    out = {"exposure_s": round(exposure_s, 5), "gain_drift": round(gain_drift, 3),
           "gain_jump_rate_hz": round(jumps_hz, 3), "noise_dn": round(noise_dn, 2),
           "image_format": "png" if png else "jpg", "jpeg_quality": quality}
    params.update({**out, "blur_px": round(exposure_s * camera.fx * speed_mps / REF_DEPTH_M, 2),
                   "png": png, "jpeg_quality": None if png else quality})
    return out


def draw_gps(rng, params: dict) -> dict:
    """1..10 Hz at a random phase; half OXTS-like (<= 0.3 m white, <= 0.15 m bias), half
    phone-like (1..3 m white, drifting bias of metres); dropouts of 2..5 s drawn in ~20 %."""
    rate = float(rng.choice(GPS_RATES_HZ))
    oxts = bool(rng.random() < 0.5)
    white = rng.uniform(0.2, 0.3) if oxts else rng.uniform(1.0, 3.0)
    bias = rng.uniform(0.02, 0.15) if oxts else rng.uniform(0.3, 2.0)
    alt = 0.5 if oxts else 2.0
    phase = float(rng.uniform(0.05, 1.0)) / rate  # the first fix comes after the first frame
    dropouts = []  # (where in the drive 0..1, length_s); app.synth.draw places them
    if rng.random() < 0.2:
        for _ in range(int(rng.integers(1, 3))):
            dropouts.append((float(rng.uniform(0.0, 1.0)), round(float(rng.uniform(2.0, 5.0)), 2)))
    out = {"gps_rate_hz": rate, "gps_phase_s": round(phase, 4),
           "gps_white_sigma_m": round(float(white), 3), "gps_bias_sigma_m": round(float(bias), 3),
           "gps_alt_sigma_m": alt, "gps_dropouts": tuple(sorted(dropouts))}
    params.update({k: v for k, v in out.items() if k != "gps_dropouts"})
    params["gps_kind"] = "oxts" if oxts else "phone"
    return out


def draw_detector(rng, params: dict) -> dict:
    out = {"det_noise_px": round(float(rng.uniform(0.3, 1.5)), 3),
           "det_miss_rate": round(float(rng.uniform(0.0, 0.2)), 3),
           "n_false_tracks": 0 if rng.random() < 0.5 else int(rng.integers(1, 5)),
           "blank_track_ids": bool(rng.random() < 0.5)}
    params.update(out)
    return out

"""One corpus journey's parameters, drawn from a seed: what real fleets vary (camera, lens, frame
rate, speed and stops, turns, scene, image quality, GPS receiver, detector).

``draw_journey`` renders nothing; it builds only the road and the true poses, to size the journey
(``MAX_FRAMES`` at most) and to record the rotation its frames really cover.
"""

from __future__ import annotations

import math

import numpy as np

from app.synth.config import SynthConfig
from app.synth.draw.parts import (GPS_RATES_HZ, draw_camera, draw_detector, draw_effects,
                                  draw_gps, draw_road, draw_scene)
from app.synth.drive.trajectory import camera_poses, fix_times
from app.synth.street.world import road_for

MAX_FRAMES = 300  # render time: 300 frames of 1920x1080 take a few minutes
APPROACH_M = (30.0, 40.0)  # straight road before the first and after the last turn
STOP_DECEL_MPS2 = 2.0
MIN_FIXES = 3
TURN_BREAK_M = 2.0  # two turns with a straight longer than this between them are two turns
ANTENNA_MAX_M = 1.5
ANTENNA_STREAM = 0xA7  # the antenna offset's random stream, apart from the journey's own


def rotation_covered(T_world_cam: np.ndarray) -> tuple[float, float]:
    """(total |yaw change|, largest single turn) in degrees over the frames' true poses. A turn
    is a run of same-direction yaw change; more than TURN_BREAK_M of straight driving ends it."""
    fwd = T_world_cam[:, :3, 2]
    dyaw = np.degrees(np.diff(np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))))
    step_m = np.linalg.norm(np.diff(T_world_cam[:, :3, 3], axis=0), axis=1)
    best = run = straight_m = 0.0
    for d, step in zip(dyaw, step_m):
        if abs(d) < 1e-6:
            straight_m += step
            if straight_m > TURN_BREAK_M:
                run = 0.0
            continue
        straight_m = 0.0
        run = run + d if run * d >= 0 else d
        best = max(best, abs(run))
    return float(np.abs(dyaw).sum()), float(best)


def _stop_fractions(rng) -> tuple[tuple[float, float], ...]:
    """One or two stops in ~25 % of journeys: (where in the drive, 0..1; dwell_s)."""
    if rng.random() >= 0.25:
        return ()
    n = 1 if rng.random() < 0.7 else 2  # two: one in each half of the drive
    where = [rng.uniform(0.0, 1.0)] if n == 1 else [rng.uniform(0.0, 0.4), rng.uniform(0.6, 1.0)]
    return tuple((float(f), round(float(rng.uniform(1.0, 3.0)), 2)) for f in where)


def _place(fractions, duration_s: float, margin_s: float = 3.0) -> tuple[tuple[float, float], ...]:
    """Times since the first frame for (fraction, length) pairs, ``margin_s`` from the ends."""
    if duration_s < 2 * margin_s:
        return ()
    return tuple((round(margin_s + f * (duration_s - 2 * margin_s), 2), d) for f, d in fractions)


def _size(cfg: SynthConfig, need_m: float, turns_mid_m: float, max_frames: int,
          stop_fractions) -> SynthConfig:
    """Frames to drive ``need_m`` from the road's start, or, past ``max_frames``, the window of
    ``max_frames`` centred on the turns; the stops placed in what is driven."""
    cfg = cfg.replace(stops=_place(stop_fractions, need_m / cfg.speed_mps))
    long = cfg.replace(n_frames=int(math.ceil(4.0 * need_m / cfg.speed_mps * cfg.fps)) + 10)
    profile = long.speed_profile()
    t_grid = np.arange(long.n_frames) / cfg.fps
    s_grid = profile.s_at(t_grid)
    n_need = min(int(np.searchsorted(s_grid, need_m)) + 1, long.n_frames)
    if n_need <= max_frames:
        return cfg.replace(n_frames=max(n_need, 2))
    window_s = (max_frames - 1) / cfg.fps
    t_mid = float(np.interp(turns_mid_m, s_grid, t_grid))
    t0 = float(np.clip(t_mid - window_s / 2, 0.0, t_grid[n_need - 1] - window_s))
    capped = cfg.replace(n_frames=max_frames, stops=_place(stop_fractions, window_s),
                         start_m=0.0)
    dist_m = capped.distance_m()
    if dist_m > cfg.world_travel_m + 10.0:  # rare: the window drives faster than the long run
        return capped.replace(world_travel_m=float(math.ceil(dist_m)))
    # The window's own stops and speed noise differ from the long run's: keep it on the road.
    last_start_m = cfg.world_travel_m + 20.0 - dist_m
    start_m = round(max(float(np.clip(float(profile.s_at(t0)), 0.0, last_start_m)), 0.0), 3)
    if start_m > last_start_m:  # rounded up past the end of the world (seed 554 by 0.2 mm)
        start_m = max(math.floor(last_start_m * 1000.0) / 1000.0, 0.0)
    return capped.replace(start_m=start_m)


def _dropouts(cfg: SynthConfig, fractions) -> SynthConfig:
    """GPS dropouts placed in the drive; one that would leave fewer than MIN_FIXES is left out."""
    if cfg.gps_rate_hz is None:
        return cfg
    duration_s = (cfg.n_frames - 1) / cfg.fps
    kept = []
    for start_s, length_s in _place(fractions, duration_s, margin_s=1.5):
        if start_s + length_s > duration_s - 1.5:
            continue
        _, keep = fix_times(duration_s, cfg.gps_rate_hz, cfg.gps_phase_s,
                            (*kept, (start_s, length_s)))
        if keep.sum() >= MIN_FIXES:
            kept.append((start_s, length_s))
    return cfg.replace(gps_dropouts=tuple(kept))


def _fit_gps(cfg: SynthConfig) -> SynthConfig:
    """A journey too short for MIN_FIXES fixes at its drawn rate gets a faster receiver (only
    short test corpora are); the phase keeps its fraction of the interval."""
    duration_s = (cfg.n_frames - 1) / cfg.fps
    for rate in (cfg.gps_rate_hz, *GPS_RATES_HZ):
        phase = round(cfg.gps_phase_s * cfg.gps_rate_hz / rate, 4)
        if rate >= cfg.gps_rate_hz and (duration_s - phase) * rate >= MIN_FIXES - 1:
            return cfg.replace(gps_rate_hz=rate, gps_phase_s=phase)
    return cfg.replace(gps_rate_hz=None, gps_phase_s=None, gps_dropouts=())


def draw_antenna_offset(seed: int) -> tuple[float, float, float]:
    """Where journey ``seed``'s GPS antenna sits from its camera (forward, left, up; metres), up
    to ANTENNA_MAX_M away: mostly behind and off to a side (a roof antenna or a receiver in the
    dashboard behind a windscreen camera; KITTI's is 1.09 m behind, 0.25 m left, 0.72 m below).
    From its own generator, so a corpus drawn with offsets has the same journeys otherwise."""
    rng = np.random.default_rng((seed, ANTENNA_STREAM))
    offset = np.array([rng.uniform(-1.5, 0.3), rng.uniform(-0.4, 0.4), rng.uniform(-0.8, 0.6)])
    norm = float(np.linalg.norm(offset))
    if norm > ANTENNA_MAX_M:
        offset *= ANTENNA_MAX_M / norm
    return tuple(round(float(v), 3) for v in offset)


def draw_journey(seed: int, max_frames: int = MAX_FRAMES, *, antenna_offset: bool = False
                 ) -> tuple[SynthConfig, dict]:
    """The config of corpus journey ``seed`` and the flat, JSON-able dict of what was drawn;
    ``antenna_offset``: its GPS antenna away from its camera (``draw_antenna_offset``), declared
    in its manifest."""
    rng = np.random.default_rng(seed)
    params: dict = {"seed": seed, "half": "tuning" if seed % 2 == 0 else "check"}
    fps = float(rng.choice([5.0, 10.0, 12.0, 15.0, 20.0, 25.0, 30.0]))
    speed = round(float(rng.uniform(3.0, 20.0)), 2)
    road = draw_road(rng, params)
    camera = draw_camera(rng, params)
    opts = {**draw_scene(rng, params), **draw_effects(rng, params, camera, speed, fps),
            **draw_gps(rng, params), **draw_detector(rng, params)}
    variation = round(float(rng.uniform(0.03, 0.15)), 3) if rng.random() < 0.5 else 0.0
    lateral_m = round(float(rng.uniform(0.0, 1.5)), 2)
    before_m, after_m = (float(rng.uniform(*APPROACH_M)) for _ in range(2))
    turns_m = sum(abs(math.radians(a)) * r for a, r in road["turn_specs"]) + sum(road["gaps"])
    need_m = before_m + turns_m + after_m
    stop_fractions = _stop_fractions(rng)
    dropout_fractions = opts.pop("gps_dropouts")
    cfg = SynthConfig(
        world_seed=seed, seed=seed, fps=fps, speed_mps=speed, camera=camera,
        turn_specs=road["turn_specs"], turn_gaps_m=road["gaps"],
        world_travel_m=float(math.ceil(need_m)), speed_variation=variation,
        decel_mps2=STOP_DECEL_MPS2, lateral_offset_m=lateral_m,
        cam_height_m=round(float(rng.uniform(1.2, 1.8)), 2),
        pitch_jitter_deg=round(float(rng.uniform(0.1, 0.6)), 2),
        roll_jitter_deg=round(float(rng.uniform(0.1, 0.4)), 2), **opts)
    road_line = road_for(cfg.world_spec())
    turns_mid_m = (road_line.turns_m[0][0] + road_line.turns_m[-1][1]) / 2
    cfg = _size(cfg, need_m, turns_mid_m, max_frames, stop_fractions)
    cfg = _dropouts(_fit_gps(cfg), dropout_fractions)
    road_line = road_for(cfg.world_spec())  # (sizing may have lengthened the world)
    t = np.arange(cfg.n_frames) / fps
    s_m = cfg.speed_profile().s_at(t)
    zeros = np.zeros(cfg.n_frames)
    T = camera_poses(road_line, s_m, cfg.lateral_offset_m, cfg.cam_height_m, zeros, zeros)
    covered, biggest = rotation_covered(T)
    params.update({
        "fps": fps, "speed_mps": speed, "speed_variation": variation,
        "n_stops": len(cfg.stops), "stops": ";".join(f"{a}+{b}" for a, b in cfg.stops),
        "stop_s": round(sum(b for _, b in cfg.stops), 2), "lateral_offset_m": lateral_m,
        "cam_height_m": cfg.cam_height_m, "n_frames": cfg.n_frames,
        "duration_s": round((cfg.n_frames - 1) / fps, 3), "start_m": cfg.start_m,
        "distance_m": round(float(s_m[-1] - s_m[0]), 2), "world_travel_m": cfg.world_travel_m,
        "n_gps_dropouts": len(cfg.gps_dropouts),
        "gps_dropouts": ";".join(f"{a}+{b}" for a, b in cfg.gps_dropouts),
        "gps_rate_hz": cfg.gps_rate_hz, "gps_phase_s": cfg.gps_phase_s,
        "covered_rotation_deg": round(covered, 2), "max_turn_deg": round(biggest, 2)})
    if antenna_offset:
        cfg = cfg.replace(gps_antenna_offset_m=draw_antenna_offset(seed))
        params["gps_antenna_offset_m"] = list(cfg.gps_antenna_offset_m)
    return cfg, params

"""A synthetic journey: a camera driving a synthetic world, its frames, GPS, detections and the
ground truth to score the pipeline against; ``write_bundle`` writes it as the contract's zip."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from app.pipeline.geometry.geodesy import LocalFrame, frame_at
from app.pipeline.types import CameraModel, Detection
from app.synth.bundle import GENERATOR_VERSION  # noqa: F401  (re-exported)
from app.synth.bundle import truth as truth_dict
from app.synth.bundle import write_journey
from app.synth.config import (KITTI_LIKE_CAMERA, STREAM_DET, STREAM_EFFECTS,  # noqa: F401
                              STREAM_FALSE_DET, STREAM_GPS, STREAM_GPS_CLOCK, STREAM_POSE,
                              SynthConfig)
from app.synth.camera.detect import (SignView, drop_missed, false_tracks, noisy_detections,
                                     visible_signs)
from app.synth.camera.effects import ImageEffects, image_effects
from app.synth.camera.render import CameraRays, Rendered, camera_rays, render_frame
from app.synth.camera.scene import Scene, build_scene
from app.synth.drive.trajectory import camera_poses, fix_times, noisy_gps, smooth_noise
from app.synth.street.world import SignTruth, World, build_world

SCENERY_AHEAD_M = 40.0


@dataclass
class SynthJourney:
    config: SynthConfig
    world: World
    origin: LocalFrame  # the ENU frame of the world and of every *_enu array here
    frame_ids: list[str]
    timestamps_s: np.ndarray  # (N,)
    s_m: np.ndarray  # (N,) road arc length of each frame
    T_world_cam: np.ndarray  # (N, 4, 4) true poses, camera -> ENU
    gps_enu: np.ndarray  # (M, 3) the noisy fixes, ENU metres (M = N: one per frame)
    lat_deg: np.ndarray  # (M,) the noisy fixes, WGS84
    lon_deg: np.ndarray
    alt_m: np.ndarray
    signs: list[SignTruth]  # the signs present in this journey's world, in track-id order
    track_ids: list[str]  # per sign
    detections: list[Detection]  # the true detections the detector kept
    views: list[SignView]  # one per detection, with the true camera-frame position
    scene: Scene
    rays: CameraRays
    gps_timestamps_s: np.ndarray | None = None  # (M,) fix times; None: the frames' timestamps
    gps_true_enu: np.ndarray | None = None  # (M, 3) where the antenna truly was at each fix
    missed_detections: list[Detection] = field(default_factory=list)
    false_detections: list[Detection] = field(default_factory=list)
    effects: ImageEffects | None = None

    @property
    def camera(self) -> CameraModel:
        return self.config.camera

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)

    @property
    def fix_timestamps_s(self) -> np.ndarray:
        return self.timestamps_s if self.gps_timestamps_s is None else self.gps_timestamps_s

    def render(self, i: int) -> Rendered:
        """The exact render of frame i, before image effects."""
        return render_frame(self.scene, self.rays, self.T_world_cam[i])

    def truth(self) -> dict:
        """The ground truth as written to ``truth.json``."""
        return truth_dict(self)

    def frames(self) -> Iterator[np.ndarray]:
        """The frames (H, W, 3) BGR uint8 as the camera delivers them, rendered one at a time."""
        for i in range(self.n_frames):
            rendered = self.render(i)
            if self.effects is None or not self.effects.active:
                yield rendered.image_bgr
            else:
                yield self.effects.apply(i, rendered, self.rays, self.T_world_cam,
                                         self.timestamps_s)


def antenna_offset_enu(cfg: SynthConfig, road, s_m: np.ndarray) -> np.ndarray:
    """(K, 3) the antenna's position minus the camera's in ENU at road arc lengths ``s_m`` (K,):
    ``cfg.gps_antenna_offset_m`` (forward, left, up) with forward along the road's tangent."""
    forward_m, left_m, up_m = cfg.gps_antenna_offset_m
    _, heading = road.at(s_m)
    forward = np.column_stack([np.cos(heading), np.sin(heading)])
    left = np.column_stack([-np.sin(heading), np.cos(heading)])
    return np.column_stack([forward_m * forward + left_m * left, np.full(len(heading), up_m)])


def _gps(cfg: SynthConfig, profile, road, rngs, timestamps, T, s_m):
    """(fix times or None, true fix positions, noisy fixes), all ENU: the antenna's."""
    with_offset = any(v != 0.0 for v in cfg.gps_antenna_offset_m)
    if cfg.gps_rate_hz is None:
        true_enu, t_fix, rate = T[:, :3, 3], None, cfg.fps
        if with_offset:
            true_enu = true_enu + antenna_offset_enu(cfg, road, s_m)
    else:
        if cfg.gps_format != "csv":
            raise ValueError("a GPS rate needs gps_format 'csv' (fixes apart from frames)")
        phase = cfg.gps_phase_s
        if phase is None:  # the receiver's clock has nothing to do with the camera's
            phase = float(rngs[STREAM_GPS_CLOCK].uniform(0.0, 1.0 / cfg.gps_rate_hz))
        t_fix, keep = fix_times(float(timestamps[-1]), cfg.gps_rate_hz, phase, cfg.gps_dropouts)
        s_fix = profile.s_at(t_fix)
        xy = road.offset(s_fix, np.full(len(s_fix), cfg.lateral_offset_m))
        true_enu, rate = np.column_stack([xy, np.full(len(s_fix), cfg.cam_height_m)]), \
            cfg.gps_rate_hz
        if with_offset:
            true_enu = true_enu + antenna_offset_enu(cfg, road, s_fix)
    # Noise on the receiver's full clock, then the dropouts: the bias drifts on through a gap.
    noisy = noisy_gps(rngs[STREAM_GPS], true_enu, rate, cfg.gps_white_sigma_m,
                      cfg.gps_bias_sigma_m, cfg.gps_bias_m, cfg.gps_alt_sigma_m)
    if t_fix is None:
        return None, true_enu, noisy
    if keep.sum() < 2:
        raise ValueError("fewer than two GPS fixes outside the dropouts")
    return t_fix[keep], true_enu[keep], noisy[keep]


def generate(cfg: SynthConfig, world: World | None = None) -> SynthJourney:
    """Everything about the journey except the pixels, which ``SynthJourney.frames`` renders.

    ``world`` may be passed to reuse one built from ``cfg.world_spec()``.
    """
    spec = cfg.world_spec()
    if world is None:
        world = build_world(spec)
    elif world.spec != spec:
        raise ValueError("the given world was built from a different WorldSpec")
    if not spec.loop and cfg.start_m + cfg.distance_m() > world.road.s_m[-1] - SCENERY_AHEAD_M:
        raise ValueError("the journey drives past the end of its world: set world_travel_m")
    streams = cfg.noise_streams()
    rngs = [np.random.default_rng(s) for s in streams]
    timestamps = np.arange(cfg.n_frames) / cfg.fps
    profile = cfg.speed_profile()
    s_m = profile.s_at(timestamps)
    jitter = smooth_noise(rngs[STREAM_POSE], cfg.n_frames, 0.5 * cfg.fps, dims=2)
    T = camera_poses(world.road, s_m, cfg.lateral_offset_m, cfg.cam_height_m,
                     np.radians(cfg.pitch_jitter_deg) * jitter[:, 0],
                     np.radians(cfg.roll_jitter_deg) * jitter[:, 1])
    t_fix, gps_true, gps_enu = _gps(cfg, profile, world.road, rngs, timestamps, T, s_m)
    origin = frame_at(cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.origin_alt_m)
    lat, lon, alt = origin.to_geodetic(gps_enu)
    scene = build_scene(world, cfg.removed_signs)
    removed = set(cfg.removed_signs)
    signs = [s for s in world.signs if s.sign_id not in removed]
    # Plate indices in the packed scene (removed signs' surfaces are gone from it).
    scene_plate = {world.signs[int(k)].sign_id: i for i, k in enumerate(scene.sign_index) if k >= 0}
    track_ids = ["" if cfg.blank_track_ids else str(k) for k in range(len(signs))]
    frame_ids = [f"{i:06d}" for i in range(cfg.n_frames)]
    views = visible_signs(cfg.camera, scene, signs, [scene_plate[s.sign_id] for s in signs], T)
    detections, views = noisy_detections(rngs[STREAM_DET], cfg.camera, views, signs, frame_ids,
                                         track_ids, cfg.det_noise_px)
    rng_false = rngs[STREAM_FALSE_DET]
    detections, views, missed = drop_missed(rng_false, detections, views, cfg.det_miss_rate)
    false = false_tracks(rng_false, cfg.camera, cfg.n_false_tracks, frame_ids, len(signs),
                         cfg.blank_track_ids)
    effects = image_effects(rngs[STREAM_EFFECTS], (cfg.seed, cfg.world_seed, STREAM_EFFECTS),
                            cfg.n_frames, cfg.fps, cfg.exposure_s, cfg.gain_drift,
                            cfg.gain_jump_rate_hz, cfg.noise_dn)
    return SynthJourney(config=cfg, world=world, origin=origin, frame_ids=frame_ids,
                        timestamps_s=timestamps, s_m=s_m, T_world_cam=T, gps_enu=gps_enu,
                        lat_deg=lat, lon_deg=lon, alt_m=alt, signs=signs, track_ids=track_ids,
                        detections=detections, views=views, scene=scene,
                        rays=camera_rays(cfg.camera), gps_timestamps_s=t_fix,
                        gps_true_enu=gps_true, missed_detections=missed, false_detections=false,
                        effects=effects)


def write_bundle(cfg: SynthConfig, out_dir: Path, world: World | None = None) -> Path:
    """Render the journey into ``out_dir/bundle.zip`` and its truth into ``out_dir/truth.json``;
    returns the bundle's path."""
    return write_journey(generate(cfg, world), Path(out_dir))

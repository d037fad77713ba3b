"""A synthetic journey: a camera driving a synthetic world, its frames, GPS, detections and the
ground truth to score the pipeline against; ``write_bundle`` writes it as the contract's zip."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Literal

import numpy as np

from app.pipeline.geodesy import LocalFrame, frame_at
from app.pipeline.types import CameraModel, Detection
from app.synth.bundle import GENERATOR_VERSION  # noqa: F401  (re-exported)
from app.synth.bundle import truth as truth_dict
from app.synth.bundle import write_journey
from app.synth.detect import SignView, noisy_detections, visible_signs
from app.synth.render import CameraRays, Rendered, camera_rays, render_frame
from app.synth.road import min_travel_m
from app.synth.scene import Scene, build_scene
from app.synth.trajectory import camera_poses, noisy_gps, smooth_noise
from app.synth.world import SignTruth, World, WorldSpec, build_world

KITTI_LIKE_CAMERA = CameraModel(width=1242, height=375, fx=959.2, fy=952.9, cx=694.4, cy=241.7,
                                k1=-0.369, k2=0.158)
SCENERY_AHEAD_M = 40.0


@dataclass(frozen=True)
class SynthConfig:
    world_seed: int = 0
    seed: int = 0  # everything that is noise: GPS, jitter, detection boxes
    n_frames: int = 120
    turns: int = 1
    loop: bool = False
    fps: float = 10.0
    speed_mps: float = 8.0
    camera: CameraModel = KITTI_LIKE_CAMERA
    cam_height_m: float = 1.65
    pitch_jitter_deg: float = 0.3
    roll_jitter_deg: float = 0.2
    lateral_offset_m: float = 0.0  # metres right of the centreline (a lane offset)
    start_m: float = 0.0  # road arc length at the first frame
    # Road length the world is built for; None: what this journey drives from start_m = 0, or the
    # least that fits the turns. Journeys share a world when their world_spec() agree.
    world_travel_m: float | None = None
    n_signs: int | None = None
    gps_white_sigma_m: float = 0.3
    gps_bias_sigma_m: float = 0.3
    gps_bias_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gps_alt_sigma_m: float = 0.5
    det_noise_px: float = 0.7
    low_texture: bool = False
    removed_signs: tuple[str, ...] = ()
    origin_lat_deg: float = 49.0110
    origin_lon_deg: float = 8.4180
    origin_alt_m: float = 112.0
    image_format: Literal["png", "jpg"] = "png"  # gps_format "exif" implies "jpg"
    jpeg_quality: int = 92
    gps_format: Literal["csv", "gpx", "exif"] = "csv"
    blank_track_ids: bool = False
    with_detections: bool = True
    camera_id: str | None = None  # default: "synth-cam-<hash of the camera model>"
    vehicle_id: str | None = "synth-vehicle"
    captured_at: str = "2025-06-01T10:00:00Z"
    camera_prior: CameraModel | None = None  # written to the manifest as a hint when given

    def world_spec(self) -> WorldSpec:
        travel = self.world_travel_m
        if travel is None:
            travel = max(float(math.ceil((self.n_frames - 1) / self.fps * self.speed_mps)),
                         float(math.ceil(min_travel_m(self.turns, self.loop))))
        return WorldSpec(world_seed=self.world_seed, turns=self.turns, loop=self.loop,
                         travel_m=travel, n_signs=self.n_signs, low_texture=self.low_texture)

    def effective_camera_id(self) -> str:
        if self.camera_id:
            return self.camera_id
        params = json.dumps([self.camera.width, self.camera.height, self.camera.params()])
        return "synth-cam-" + hashlib.sha1(params.encode()).hexdigest()[:10]

    def frame_format(self) -> str:
        return "jpg" if self.gps_format == "exif" else self.image_format

    def replace(self, **changes) -> "SynthConfig":
        return dataclasses.replace(self, **changes)


@dataclass
class SynthJourney:
    config: SynthConfig
    world: World
    origin: LocalFrame  # the ENU frame of the world and of every *_enu array here
    frame_ids: list[str]
    timestamps_s: np.ndarray  # (N,)
    s_m: np.ndarray  # (N,) road arc length of each frame
    T_world_cam: np.ndarray  # (N, 4, 4) true poses, camera -> ENU
    gps_enu: np.ndarray  # (N, 3) the noisy fixes, ENU metres
    lat_deg: np.ndarray  # (N,) the noisy fixes, WGS84
    lon_deg: np.ndarray
    alt_m: np.ndarray
    signs: list[SignTruth]  # the signs present in this journey's world, in track-id order
    track_ids: list[str]  # per sign
    detections: list[Detection]
    views: list[SignView]  # one per detection, with the true camera-frame position
    scene: Scene
    rays: CameraRays

    @property
    def camera(self) -> CameraModel:
        return self.config.camera

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)

    def render(self, i: int) -> Rendered:
        return render_frame(self.scene, self.rays, self.T_world_cam[i])

    def truth(self) -> dict:
        """The ground truth as written to ``truth.json``."""
        return truth_dict(self)

    def frames(self) -> Iterator[np.ndarray]:
        """The frames (H, W, 3) BGR uint8, rendered one at a time."""
        for i in range(self.n_frames):
            yield self.render(i).image_bgr


def generate(cfg: SynthConfig, world: World | None = None) -> SynthJourney:
    """Everything about the journey except the pixels, which ``SynthJourney.frames`` renders.

    ``world`` may be passed to reuse one built from ``cfg.world_spec()``.
    """
    spec = cfg.world_spec()
    if world is None:
        world = build_world(spec)
    elif world.spec != spec:
        raise ValueError("the given world was built from a different WorldSpec")
    distance_m = (cfg.n_frames - 1) / cfg.fps * cfg.speed_mps
    if not spec.loop and cfg.start_m + distance_m > world.road.s_m[-1] - SCENERY_AHEAD_M:
        raise ValueError("the journey drives past the end of its world: set world_travel_m")
    seeds = np.random.SeedSequence([cfg.seed, cfg.world_seed]).spawn(3)
    rng_pose, rng_gps, rng_det = (np.random.default_rng(s) for s in seeds)
    timestamps = np.arange(cfg.n_frames) / cfg.fps
    s_m = cfg.start_m + cfg.speed_mps * timestamps
    jitter = smooth_noise(rng_pose, cfg.n_frames, 0.5 * cfg.fps, dims=2)
    T = camera_poses(world.road, s_m, cfg.lateral_offset_m, cfg.cam_height_m,
                     np.radians(cfg.pitch_jitter_deg) * jitter[:, 0],
                     np.radians(cfg.roll_jitter_deg) * jitter[:, 1])
    gps_enu = noisy_gps(rng_gps, T[:, :3, 3], cfg.fps, cfg.gps_white_sigma_m, cfg.gps_bias_sigma_m,
                        cfg.gps_bias_m, cfg.gps_alt_sigma_m)
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
    detections, views = noisy_detections(rng_det, cfg.camera, views, signs, frame_ids, track_ids,
                                         cfg.det_noise_px)
    return SynthJourney(config=cfg, world=world, origin=origin, frame_ids=frame_ids,
                        timestamps_s=timestamps, s_m=s_m, T_world_cam=T, gps_enu=gps_enu,
                        lat_deg=lat, lon_deg=lon, alt_m=alt, signs=signs, track_ids=track_ids,
                        detections=detections, views=views, scene=scene,
                        rays=camera_rays(cfg.camera))


def write_bundle(cfg: SynthConfig, out_dir: Path, world: World | None = None) -> Path:
    """Render the journey into ``out_dir/bundle.zip`` and its truth into ``out_dir/truth.json``;
    returns the bundle's path."""
    return write_journey(generate(cfg, world), Path(out_dir))

"""``SynthConfig``: everything a synthetic journey depends on. Every default reproduces the original
generator (one kind of journey: ~90 degree turns, constant speed, a KITTI-like camera, one GPS fix
per frame), so configs that leave the newer fields alone render the same files as before."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from app.pipeline.types import CameraModel
from app.synth.drive.speed import SpeedProfile, speed_profile
from app.synth.street.road import TurnSpecs, min_travel_m
from app.synth.street.world import WorldSpec

KITTI_LIKE_CAMERA = CameraModel(width=1242, height=375, fx=959.2, fy=952.9, cx=694.4, cy=241.7,
                                k1=-0.369, k2=0.158)

# Child streams of SeedSequence([seed, world_seed]); 0-2 are the original pose, GPS and detection
# noise, so adding streams leaves those draws unchanged.
STREAM_POSE, STREAM_GPS, STREAM_DET, STREAM_SPEED, STREAM_FALSE_DET, STREAM_EFFECTS, \
    STREAM_GPS_CLOCK = range(7)


@dataclass(frozen=True)
class SynthConfig:
    world_seed: int = 0
    seed: int = 0  # everything that is noise: GPS, jitter, detection boxes
    n_frames: int = 120
    turns: int = 1
    loop: bool = False
    fps: float = 10.0
    speed_mps: float = 8.0  # cruise speed
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
    # Where the GPS antenna is: its position minus the camera's, metres, in the vehicle's axes
    # (forward along the road, left, up); the fixes are the antenna's. Declared in the manifest's
    # gps_antenna_offset_m when gps_antenna_offset_declared and the offset is not zero.
    gps_antenna_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gps_antenna_offset_declared: bool = True
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
    # Road: explicit (signed angle_deg, radius_m) turns, positive = left, instead of `turns`
    # random ~90 degree ones; turn_gaps_m: straight metres between consecutive turns (0 joins
    # arcs, e.g. a roundabout's entry, circle and exit), None: spread like the random turns.
    turn_specs: TurnSpecs | None = None
    turn_gaps_m: tuple[float, ...] | None = None
    scene_density: float = 0.5  # 0 sparse suburb .. 1 dense city
    repeated_facades: bool = False  # a few facade textures shared by all building walls
    # Speed: exp(speed_variation x smooth noise) times cruise; stops are (t_rest_s, dwell_s)
    # since the first frame, braking and accelerating at decel_mps2.
    speed_variation: float = 0.0
    stops: tuple[tuple[float, float], ...] = ()
    decel_mps2: float = 2.0
    # Image effects after rendering (app.synth.camera.effects); 0 = off.
    exposure_s: float = 0.0  # motion blur: the camera's motion during this exposure time
    gain_drift: float = 0.0  # std of the slow log-brightness drift
    gain_jump_rate_hz: float = 0.0  # auto-exposure jumps of +-10..30 % per second
    noise_dn: float = 0.0  # sensor noise std, 8-bit digital numbers
    # GPS receiver clock: None = one fix per frame at its timestamp (the original); else fixes at
    # gps_rate_hz from gps_phase_s after the first frame (None: a random phase), with no fix inside
    # the (start_s, length_s) gps_dropouts. gps.csv then has frame rows without a position and
    # fix rows without a frame.
    gps_rate_hz: float | None = None
    gps_phase_s: float | None = None
    gps_dropouts: tuple[tuple[float, float], ...] = ()
    # Detector: each true detection is missed with det_miss_rate; n_false_tracks short tracks of
    # boxes where no sign is (listed in truth.json as false_detections).
    det_miss_rate: float = 0.0
    n_false_tracks: int = 0

    def noise_streams(self) -> list[np.random.SeedSequence]:
        return np.random.SeedSequence([self.seed, self.world_seed]).spawn(STREAM_GPS_CLOCK + 1)

    def speed_profile(self) -> SpeedProfile:
        rng = np.random.default_rng(self.noise_streams()[STREAM_SPEED])
        return speed_profile(rng, self.start_m, self.speed_mps, (self.n_frames - 1) / self.fps,
                             self.speed_variation, self.stops, self.decel_mps2)

    def distance_m(self) -> float:
        """Road driven from the first frame to the last."""
        if self.speed_variation == 0.0 and not self.stops:
            return (self.n_frames - 1) / self.fps * self.speed_mps
        return float(self.speed_profile().s_at((self.n_frames - 1) / self.fps)) - self.start_m

    def world_spec(self) -> WorldSpec:
        travel = self.world_travel_m
        specs = None if self.turn_specs is None else tuple(tuple(map(float, t))
                                                           for t in self.turn_specs)
        gaps = None if self.turn_gaps_m is None else tuple(map(float, self.turn_gaps_m))
        turns = self.turns if specs is None else len(specs)
        if travel is None:
            travel = max(float(math.ceil(self.distance_m())),
                         float(math.ceil(min_travel_m(turns, self.loop, specs, gaps))))
        return WorldSpec(world_seed=self.world_seed, turns=turns, loop=self.loop,
                         travel_m=travel, n_signs=self.n_signs, low_texture=self.low_texture,
                         turn_specs=specs, turn_gaps_m=gaps, density=self.scene_density,
                         repeated_facades=self.repeated_facades)

    def effective_camera_id(self) -> str:
        if self.camera_id:
            return self.camera_id
        params = json.dumps([self.camera.width, self.camera.height, self.camera.params()])
        return "synth-cam-" + hashlib.sha1(params.encode()).hexdigest()[:10]

    def frame_format(self) -> str:
        return "jpg" if self.gps_format == "exif" else self.image_format

    def replace(self, **changes) -> "SynthConfig":
        return dataclasses.replace(self, **changes)

"""A fleet corpus: cameras that each come back in several journeys (issue 66's per-camera bars).

Camera ``c`` (a seed) gets ``FLEET_JOURNEYS`` journeys, each drawn as an ordinary corpus journey
(its own road, speed, scene, GPS receiver and detector: another day, route and driver) but seen
through the one lens drawn from the camera's seed, under one ``camera_id``. The half is the
camera's (by its seed's parity), so a camera's journeys are all tuned on or all checked.
"""

from __future__ import annotations

import numpy as np

from app.synth.config import SynthConfig
from app.synth.draw import MAX_FRAMES, draw_journey
from app.synth.draw.parts import draw_camera

FLEET_JOURNEYS = (3, 8)  # journeys per camera, inclusive
# Journey seeds of a fleet camera: far from the ordinary corpus's (which count up from 0).
_JOURNEY_SEED_BASE = 1_000_000
_CAMERA_STREAM = 66  # the camera's lens and journey count are drawn from (this, camera seed)


def fleet_camera_id(camera_seed: int) -> str:
    return f"fleet-{camera_seed:04d}"


def fleet_journey_name(camera_seed: int, k: int) -> str:
    return f"f{camera_seed:04d}-{k}"


def fleet_size(camera_seed: int) -> int:
    """How many journeys camera ``camera_seed`` drives."""
    rng = np.random.default_rng([_CAMERA_STREAM, camera_seed])
    return int(rng.integers(FLEET_JOURNEYS[0], FLEET_JOURNEYS[1] + 1))


def draw_fleet_journey(camera_seed: int, k: int,
                       max_frames: int = MAX_FRAMES) -> tuple[SynthConfig, dict]:
    """Journey ``k`` (0-based) of camera ``camera_seed``: ``draw_journey`` of its own seed, with
    the camera's lens and id in place of the drawn ones (the journey's blur, an exposure time,
    stays as drawn). ``params`` records the camera's true intrinsics and ``camera_seed``."""
    seed = _JOURNEY_SEED_BASE + 10 * camera_seed + k
    cfg, params = draw_journey(seed, max_frames)
    rng = np.random.default_rng([_CAMERA_STREAM, camera_seed])
    rng.integers(FLEET_JOURNEYS[0], FLEET_JOURNEYS[1] + 1)  # fleet_size's draw
    camera_params: dict = {}
    camera = draw_camera(rng, camera_params)
    params.update(camera_params)
    params.update({"camera_seed": camera_seed, "journey_index": k,
                   "half": "tuning" if camera_seed % 2 == 0 else "check",
                   "camera_id": fleet_camera_id(camera_seed)})
    return cfg.replace(camera=camera, camera_id=fleet_camera_id(camera_seed)), params

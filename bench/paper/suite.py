"""The benchmark's fixed journeys (synthetic, rendered once and cached) and what runs on each.

Variants run on a journey:

* ``ours``: the product pipeline, self-calibrating (or, with ``known_from``, given the calibration
  another journey of the same camera produced: a journey without a turn cannot calibrate itself);
* ``ours_alt``: the same calibration, the other GPS alignment (``short`` if the configured one is
  ``full``, and vice versa: the paper's full-vs-short trajectory comparison);
* ``gt`` / ``gt_alt``: the pipeline given the true camera (``reuse_known_calibration``): the
  accuracy ceiling, with the configured / the other alignment;
* ``naive``: COLMAP over every frame with default options (``bench.paper.naive``): the speed floor.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from app.synth.journey import GENERATOR_VERSION, SynthConfig, write_bundle

VARIANTS = ("ours", "ours_alt", "gt", "gt_alt", "naive")


@dataclass(frozen=True)
class JourneySpec:
    name: str
    synth: SynthConfig
    variants: tuple[str, ...]
    description: str
    # Journey (earlier in the suite, same camera) whose ``ours`` calibration this one is given.
    known_from: str | None = None
    # The naive baseline costs ~2.5 s per frame: it runs on the first frames only.
    naive_max_frames: int | None = None
    # Frames of plain SIFT extraction timed beside the runs (``naive.plain_sift_s``; its cost is
    # linear in the frames, so a prefix gives its rate); 0: not timed.
    sift_frames: int = 0


def quick_suite() -> list[JourneySpec]:
    """One short turn journey: ours, the ground-truth camera and the naive pipeline on a prefix;
    and a long one at a dashcam's usual spacing (frames 1.05 m apart: SIFT ego-motion), ours and a
    calibrated camera's run, timed against plain SIFT extraction, and the calibrated camera's run
    on the first half of it, whose peak memory shows whether memory grows with the length."""
    return [JourneySpec("turn-70", SynthConfig(n_frames=70, turns=1), ("ours", "gt", "naive"),
                        "70 frames, one turn", naive_max_frames=30),
            long_journey()]


def long_journey() -> JourneySpec:
    return JourneySpec("long-600", SynthConfig(n_frames=600, turns=2, speed_mps=10.5,
                                               world_seed=5, seed=5),
                       ("ours", "gt", "gt_half"),
                       "600 frames, two turns, 10.5 m/s (frames 1.05 m apart)",
                       sift_frames=120)


def full_suite() -> list[JourneySpec]:
    loop = SynthConfig(n_frames=300, loop=True, world_seed=0, seed=0)
    return [
        JourneySpec("loop-300", loop, VARIANTS, "300 frames, a closed loop (4 turns) and back "
                    "past the start", naive_max_frames=100),
        JourneySpec("straight-200", SynthConfig(n_frames=200, turns=0, world_seed=1, seed=1),
                    ("ours", "ours_alt", "gt", "gt_alt"),
                    "200 frames, no turn, same camera: given loop-300's calibration",
                    known_from="loop-300"),
        JourneySpec("lowtex-gps3m-150",
                    SynthConfig(n_frames=150, turns=1, world_seed=3, seed=3, low_texture=True,
                                gps_white_sigma_m=1.5, gps_bias_sigma_m=1.5,
                                gps_alt_sigma_m=2.0),
                    ("ours", "gt"), "150 frames, one turn, low texture, GPS noise 1.5 m white "
                    "+ 1.5 m bias"),
        JourneySpec("long-1000", SynthConfig(n_frames=1000, turns=3, world_seed=2, seed=2),
                    ("ours",), "1000 frames, three turns: throughput"),
    ]


def sensitivity_journey(quick: bool = False) -> JourneySpec:
    cfg = SynthConfig(n_frames=70 if quick else 120, turns=1, world_seed=4, seed=4)
    return JourneySpec(f"sensitivity-{cfg.n_frames}", cfg, ("gt",),
                       f"{cfg.n_frames} frames, one turn: one-at-a-time camera errors")


def ensure_journey(spec: JourneySpec, cache_dir: Path) -> tuple[Path, dict]:
    """(bundle.zip, truth dict) of ``spec``, rendered on first use into ``cache_dir``.

    The cache key is the synth config and the generator version, as in the tests' cache.
    """
    digest = hashlib.sha256(repr((GENERATOR_VERSION, spec.synth)).encode()).hexdigest()[:12]
    out = cache_dir / f"{spec.name}-{digest}"
    if not (out / "truth.json").exists():
        write_bundle(spec.synth, out)
    return out / "bundle.zip", json.loads((out / "truth.json").read_text())

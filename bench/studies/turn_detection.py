"""``signmap bench turns``: the turn finder against the truth, over corpus journeys, without
rendering a pixel (seconds per journey).

For each journey drawn by ``synth.draw.draw_journey`` its GPS fixes are interpolated to the frames
as the bundle reader does, and the plan's turn finding (``plan.turns_and_candidates``:
``turns.smooth_track`` + ``turns.find_turns`` with the config's knobs) runs on them. A journey
whose true poses hold a turn of 45 deg or more and where no turn is found would be refused with
"no turn"; a journey whose largest true turn is under 30 deg and where one is found would spend
calibration on a bend that cannot calibrate. Each variant (``--variant name:knob=value,...``) is
one row.

A second table lists, per variant, the journeys whose calibration candidate windows hold other
frames than the defaults' (``plan.turns_and_candidates``, as the plan builds them). Only those
can calibrate differently under ``colmap_reproducible``, so a calibration run comparing the
variant need render and run only them (docs/decisions/rdp-tolerance.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.bundle.gps import FrameGps, GpsFixes, NumberedLabels, interpolate_to_frames
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import LocalFrame, frame_at
from app.pipeline.geometry.gps_noise import white_noise_m
from app.pipeline.steps.plan import turns_and_candidates
from app.synth.draw import draw_journey, rotation_covered
from app.synth.journey import SynthJourney, generate

TURN_DEG = 45.0  # a journey with a true turn at least this large must calibrate
GENTLE_DEG = 30.0  # ... and one whose largest is under this must not find a turn


@dataclass(frozen=True)
class JourneyTrack:
    """One journey's per-frame metric GPS ``xy_m`` (N, 2), ``timestamp_s`` (N,) and truth;
    ``gps_noise_m``: its fixes' white noise as the pipeline measures it."""

    name: str
    half: str
    true_largest_deg: float
    xy_m: np.ndarray
    timestamp_s: np.ndarray
    gps_noise_m: float | None = None


@dataclass
class CorpusGps:
    """A corpus journey, generated without rendering, with its GPS read as the pipeline reads it."""

    journey: SynthJourney
    params: dict
    frames: FrameGps  # the fixes interpolated to the frames
    origin: LocalFrame  # at the first frame


def corpus_gps(seed: int) -> CorpusGps:
    cfg, params = draw_journey(seed)
    j = generate(cfg)
    fixes = GpsFixes(j.fix_timestamps_s, j.lat_deg, j.lon_deg, j.alt_m,
                     NumberedLabels("fix", np.arange(len(j.fix_timestamps_s))))
    frames = interpolate_to_frames(fixes, j.timestamps_s, j.frame_ids)
    return CorpusGps(j, params, frames,
                     frame_at(float(frames.lat_deg[0]), float(frames.lon_deg[0]), None))


def journey_track(seed: int) -> JourneyTrack:
    gps = corpus_gps(seed)
    j, params, frames, t_fix = gps.journey, gps.params, gps.frames, gps.journey.fix_timestamps_s
    xy_m = gps.origin.to_local(frames.lat_deg, frames.lon_deg, None)[:, :2]
    _, largest = rotation_covered(j.T_world_cam[frames.kept])
    return JourneyTrack(f"c{seed:04d}", params["half"], largest, xy_m, frames.timestamp_s,
                        white_noise_m(t_fix, j.lat_deg, j.lon_deg))


def largest_found_deg(track: JourneyTrack, config: PipelineConfig) -> float:
    """Rotation (deg) of the largest turn window the plan would find on ``track``."""
    found, _, _ = turns_and_candidates(track.xy_m, track.timestamp_s, config, track.gps_noise_m)
    return max((w.rotation_deg for w in found), default=0.0)


def candidate_frames(track: JourneyTrack, config: PipelineConfig) -> list[tuple[int, ...]]:
    """The frames of each calibration candidate window the plan would build on ``track``."""
    _, windows, _ = turns_and_candidates(track.xy_m, track.timestamp_s, config, track.gps_noise_m)
    return [tuple(int(i) for i in w.frame_idx) for w in windows]


def moved_table(tracks: list[JourneyTrack], variants: dict[str, PipelineConfig],
                base: PipelineConfig) -> str:
    """Per variant and half, the journeys whose candidate frames differ from ``base``'s."""
    lines = ["| variant | half | journeys whose candidate frames move |", "| --- | --- | --- |"]
    before = {t.name: candidate_frames(t, base) for t in tracks}
    for name, config in variants.items():
        for half in sorted({t.half for t in tracks}, reverse=True):
            moved = [t.name for t in tracks
                     if t.half == half and candidate_frames(t, config) != before[t.name]]
            lines.append(f"| {name} | {half} | {len(moved)}: {' '.join(moved) or '–'} |")
    return "\n".join(lines)


def table(tracks: list[JourneyTrack], variants: dict[str, PipelineConfig]) -> str:
    lines = ["| variant | half | turns ≥ 45° found | missed (true / found deg) | gentle < 30° "
             "with a turn found (true / found deg) |", "| --- | --- | --- | --- | --- |"]
    for name, config in variants.items():
        for half in sorted({t.half for t in tracks}, reverse=True):
            mine = [t for t in tracks if t.half == half]
            found = {t.name: largest_found_deg(t, config) for t in mine}
            big = [t for t in mine if t.true_largest_deg >= TURN_DEG]
            missed = [t for t in big if found[t.name] == 0.0]
            false = [t for t in mine if t.true_largest_deg < GENTLE_DEG and found[t.name] > 0.0]
            lines.append(
                f"| {name} | {half} | {len(big) - len(missed)}/{len(big)} | "
                + (", ".join(f"{t.name} ({t.true_largest_deg:.0f} / {found[t.name]:.0f})"
                             for t in missed) or "–") + " | "
                + (", ".join(f"{t.name} ({t.true_largest_deg:.0f} / {found[t.name]:.0f})"
                             for t in false) or "–") + " |")
    return "\n".join(lines)


def parse_variant(text: str) -> tuple[str, dict[str, str]]:
    """``name:knob=value,knob=value`` -> (name, {knob: value})."""
    name, _, knobs = text.partition(":")
    pairs = [kv.split("=", 1) for kv in knobs.split(",") if kv]
    if not name or not pairs or any(len(p) != 2 for p in pairs):
        raise ValueError(f"expected name:knob=value,..., got {text!r}")
    return name, dict(pairs)


def run(n: int, seed: int, variants: list[str], half: str | None = None) -> str:
    configs = {"defaults": PipelineConfig()}
    for text in variants:
        name, knobs = parse_variant(text)
        configs[name] = PipelineConfig(**knobs)
    seeds = [s for s in range(seed, seed + n) if not half or draw_journey(s)[1]["half"] == half]
    tracks = [journey_track(s) for s in seeds]
    others = {k: v for k, v in configs.items() if k != "defaults"}
    return table(tracks, configs) + (
        "\n\n" + moved_table(tracks, others, configs["defaults"]) if others else "")

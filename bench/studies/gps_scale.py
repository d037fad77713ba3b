"""``signmap bench gps-scale``: how well a window's GPS alignment can fix its scale, per way of
placing frames between GPS fixes, over corpus journeys drawn without rendering a pixel.

A window's scale comes from one similarity between its camera centres and its frames' GPS
positions, and nearly all of a placed sign's error in its cameras' frame is that scale (along the
ray). Here the camera centres are the journey's true ones, so the fitted scale's error is what the
GPS positions alone cost: for each drawn journey, its fixes are read as the bundle reader reads
them (straight lines, ``bundle.gps``) and, as a variant, through ``geometry.gps_track``'s
smoothing spline; windows of ``WINDOW_FRAMES`` frames every ``WINDOW_STRIDE`` (the ego-motion
windows' size and overlap at step 2) are fitted as the pipeline fits them
(``similarity.align_trajectory``, gravity for a straight window's roll), and their scale error is
reported per GPS kind and half: rms, median and 90th percentile of |error|. Windows where the car
moves less than ``MIN_WINDOW_M``, or that cannot be aligned, are left out, as the pipeline drops
them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.geometry.gps_noise import white_noise_m
from app.pipeline.geometry.gps_track import smoothed_positions
from app.pipeline.geometry.similarity import align_trajectory
from app.synth.draw import draw_journey
from bench.studies.turn_detection import corpus_gps

WINDOW_FRAMES = 80
WINDOW_STRIDE = 64
MIN_WINDOW_M = 5.0


@dataclass(frozen=True)
class JourneyScales:
    """One journey's window scale errors (fitted / true - 1) per method."""

    name: str
    half: str
    gps_kind: str
    errors: dict[str, np.ndarray]


def journey_scales(seed: int) -> JourneyScales:
    gps = corpus_gps(seed)
    j, params, frames, origin = gps.journey, gps.params, gps.frames, gps.origin
    t_fix = j.fix_timestamps_s
    xyz_lines = origin.to_local(frames.lat_deg, frames.lon_deg, None)
    xyz_fix = origin.to_local(j.lat_deg, j.lon_deg, None)
    xyz_fix[:, 2] = np.nan  # horizontal only, as the corpus's journeys carry no altitude
    noise_m = white_noise_m(t_fix, j.lat_deg, j.lon_deg)
    positions = {"lines": xyz_lines,
                 "spline": smoothed_positions(frames.timestamp_s, xyz_lines, t_fix, xyz_fix,
                                              noise_m)}
    T_true = j.T_world_cam[frames.kept]
    c_true = T_true[:, :3, 3]
    errors: dict[str, list[float]] = {m: [] for m in positions}
    for a in range(0, max(1, len(c_true) - WINDOW_FRAMES + WINDOW_STRIDE), WINDOW_STRIDE):
        rows = slice(a, min(len(c_true), a + WINDOW_FRAMES))
        if np.linalg.norm(np.ptp(c_true[rows], axis=0)) < MIN_WINDOW_M:
            continue
        try:
            scales = {method: align_trajectory(c_true[rows], xyz[rows],
                                               T_true[rows, :3, :3])[0].scale
                      for method, xyz in positions.items()}
        except ValueError:  # degenerate (GPS standing still): the pipeline drops such windows
            continue
        for method, scale in scales.items():
            errors[method].append(scale - 1.0)
    return JourneyScales(f"c{seed:04d}", params["half"], params["gps_kind"],
                         {m: np.array(e) for m, e in errors.items()})


def table(journeys: list[JourneyScales]) -> str:
    lines = ["| GPS | half | journeys | windows | method | rms | median abs | p90 abs |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for kind in sorted({j.gps_kind for j in journeys}, reverse=True):
        for half in ("tuning", "check"):
            mine = [j for j in journeys if j.gps_kind == kind and j.half == half]
            if not mine:
                continue
            for method in mine[0].errors:
                e = np.abs(np.concatenate([j.errors[method] for j in mine]))
                if not len(e):
                    continue
                lines.append(f"| {kind} | {half} | {len(mine)} | {len(e)} | {method} | "
                             f"{100 * np.sqrt(np.mean(e**2)):.2f} % | "
                             f"{100 * np.median(e):.2f} % | {100 * np.percentile(e, 90):.2f} % |")
    return "\n".join(lines)


def run(n: int, seed: int, half: str | None = None) -> str:
    seeds = [s for s in range(seed, seed + n) if not half or draw_journey(s)[1]["half"] == half]
    return table([journey_scales(s) for s in seeds])

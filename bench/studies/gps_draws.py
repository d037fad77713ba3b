"""``signmap bench gps-draws``: a suite journey's sign errors over fresh draws of its GPS noise.

A suite journey is rendered with one draw of GPS noise, and its absolute sign error is mostly
that draw's slowly wandering bias: on loop-300 (true camera, 120-frame windows) the median
absolute error ran from 0.18 to 0.58 m over 30 draws, with the same images and reconstruction.
A knob compared on the one draw the suite renders is compared on that draw's luck.

This reconstructs the journey once per variant, with the true camera (the suite's ``gt``
variant: ``reuse_known_calibration``), then georeferences each reconstruction under the same
``draws`` fresh draws of the journey's own noise model (``drive.trajectory.noisy_gps`` with its
``SynthConfig`` sigmas, seeds ``DRAW_SEED0 + k``), so variants meet the same draws and are
compared pair by pair. Each variant is reconstructed once, so a difference also holds one
sample of COLMAP's run-to-run variation (two threads): a variant changing nothing differed from
the defaults by 0.001 m in absolute and 0.002 m in relative error (loop-300). Only journeys
with one GPS position per frame (``gps_rate_hz`` None, as every suite journey) can be drawn
again.

Frames: ``true_enu`` is the truth's ENU frame (``bench.paper.metrics.truth_frame``); a redrawn fix
goes through WGS84 into the reconstruction's own frame (``Reconstruction.origin``), as the bundle
reader would take it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import LocalFrame
from app.pipeline.geometry.gps_noise import white_noise_m
from app.pipeline.types import GpsTrack, Journey
from app.synth.config import SynthConfig
from app.synth.drive.trajectory import noisy_gps

DRAW_SEED0 = 10_000  # draw k uses seed DRAW_SEED0 + k: every variant meets the same draws


@dataclass(frozen=True)
class DrawnGps:
    """One draw of a journey's per-frame GPS: geodetic (N,) arrays and ``xyz_m`` (N, 3) in the
    reconstruction's frame."""

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    xyz_m: np.ndarray


def draw_gps(true_enu: np.ndarray, synth: SynthConfig, truth_frame: LocalFrame,
             recon_frame: LocalFrame, seed: int) -> DrawnGps:
    """Fresh noisy fixes of the true camera centres ``true_enu`` (N, 3, truth ENU, one per
    frame) under ``synth``'s GPS noise model, in ``recon_frame``."""
    if synth.gps_rate_hz is not None:
        raise ValueError("only journeys with one GPS position per frame can be drawn again")
    noisy_enu = noisy_gps(np.random.default_rng(seed), np.asarray(true_enu, float), synth.fps,
                          synth.gps_white_sigma_m, synth.gps_bias_sigma_m, synth.gps_bias_m,
                          synth.gps_alt_sigma_m)
    lat, lon, alt = truth_frame.to_geodetic(noisy_enu)
    return DrawnGps(lat, lon, alt, recon_frame.to_local(lat, lon, alt))


def with_gps(journey: Journey, recon, drawn: DrawnGps, config: PipelineConfig):
    """(journey, reconstruction) whose GPS is ``drawn``: what the bundle reader and
    ``run.reconstruct`` would have made of it (the fixes, their measured noise, the positions
    the alignment takes)."""
    from app.pipeline.run import frame_positions

    t_s = journey.timestamps_s
    fixes = (GpsTrack(t_s, drawn.lat_deg, drawn.lon_deg, drawn.alt_m)
             if journey.gps_fixes is not None else None)
    noise_m = (white_noise_m(t_s, drawn.lat_deg, drawn.lon_deg) if fixes is not None
               else journey.gps_noise_m)
    journey = replace(journey, lat_deg=drawn.lat_deg, lon_deg=drawn.lon_deg, alt_m=drawn.alt_m,
                      gps_fixes=fixes, gps_noise_m=noise_m)
    xyz_align = (frame_positions(journey, recon.origin, drawn.xyz_m) if config.gps_smoothing
                 else drawn.xyz_m)
    return journey, replace(recon, xyz_gps=drawn.xyz_m, xyz_align=xyz_align)


METRICS = ("abs_median_m", "abs_mean_m", "rel_mean_m")


def suite_spec(name: str, seed: int | None = None):
    """Suite journey ``name``; with ``seed``, the same kind of journey in another world and with
    other noise (its ``SynthConfig`` seed and world seed), named ``<name>-s<seed>``."""
    from bench.paper.suite import full_suite, quick_suite

    specs = {s.name: s for s in quick_suite() + full_suite()}
    if name not in specs:
        raise ValueError(f"no suite journey {name!r} (one of {', '.join(specs)})")
    spec = specs[name]
    if seed is None:
        return spec
    return replace(spec, name=f"{name}-s{seed}",
                   synth=spec.synth.replace(seed=seed, world_seed=seed))


def draws_of_variant(spec, draws: int, knobs: dict, cache_dir: Path) -> list[dict]:
    """Per draw (k = -1: the journey's own GPS, then 0 .. draws - 1) the sign summary of suite
    journey ``spec`` (``suite_spec``) reconstructed once with the true camera and ``knobs``."""
    from app.pipeline.bundle import read_bundle
    from app.pipeline.run import georeference, reconstruct
    from app.pipeline.types import CameraModel
    from bench.corpus.run import pipeline_config
    from bench.paper.metrics import truth_frame
    from bench.paper.metrics import evaluate_result, truth_centres_enu
    from bench.paper.suite import ensure_journey

    bundle, truth = ensure_journey(spec, cache_dir)
    cam = truth["camera"]
    camera = CameraModel.from_params(cam["width"], cam["height"], cam)
    config = pipeline_config({**knobs, "reuse_known_calibration": True})
    with tempfile.TemporaryDirectory(prefix="gps-draws-") as tmp:
        journey = read_bundle(bundle, Path(tmp) / "bundle")
        recon = reconstruct(journey, config, Path(tmp) / "work", known_camera=camera)
    centres_enu = truth_centres_enu(truth)
    true_enu = np.array([centres_enu[f.frame_id] for f in journey.frames])
    truth_enu_frame = truth_frame(truth)
    rows = []
    for k in range(-1, draws):
        j, r = journey, recon
        if k >= 0:
            drawn = draw_gps(true_enu, spec.synth, truth_enu_frame, recon.origin, DRAW_SEED0 + k)
            j, r = with_gps(journey, recon, drawn, config)
        signs = evaluate_result(georeference(j, r, config), truth)["signs"]
        rows.append({"journey": spec.name, "draw": k, "n_signs": signs["n_signs"],
                     "n_false": signs["n_false"], **{m: signs[m] for m in METRICS}})
    return rows


def table(name: str, results: dict[str, list[dict]]) -> str:
    """Markdown: per variant and metric, the mean / median / p90 over the fresh draws (of every
    journey), the suite's own draw (the mean over journeys), and the mean paired difference to
    the first variant (± its standard error) with the number of draws where the variant is
    lower."""
    base = next(iter(results))
    fresh = {v: sorted((r for r in rows if r["draw"] >= 0),
                       key=lambda r: (r["journey"], r["draw"])) for v, rows in results.items()}
    journeys = sorted({r["journey"] for r in fresh[base]})
    lines = [f"{name}, true camera: sign errors (m) over {len(fresh[base])} fresh GPS draws"
             + (f" of {len(journeys)} journeys ({', '.join(journeys)})" if len(journeys) > 1
                else ""),
             "", f"| variant | signs placed | false | metric | mean | median | p90 | own draw | "
             f"vs {base}: mean diff ± se | lower in |", "| --- " * 10 + "|"]
    for v, rows in fresh.items():
        own = [r for r in results[v] if r["draw"] < 0]
        n_signs = [r["n_signs"] for r in rows]
        placed = f"{min(n_signs)}-{max(n_signs)}"
        false = str(sum(r["n_false"] for r in rows))
        for m in METRICS:
            x = np.array([r[m] for r in rows], float)
            cells = [v, placed, false, m, f"{x.mean():.3f}", f"{np.median(x):.3f}",
                     f"{np.percentile(x, 90):.3f}", f"{np.mean([r[m] for r in own]):.3f}"]
            if v == base:
                cells += ["–", "–"]
            else:
                d = x - np.array([r[m] for r in fresh[base]], float)
                se = d.std(ddof=1) / np.sqrt(len(d))
                cells += [f"{d.mean():+.3f} ± {se:.3f}", f"{int((d < 0).sum())}/{len(d)}"]
            lines.append("| " + " | ".join(cells) + " |")
    if len(journeys) > 1:
        lines += ["", "Per journey, means over its draws:", "",
                  "| journey | variant | signs placed | " + " | ".join(METRICS) + " |",
                  "| --- " * (3 + len(METRICS)) + "|"]
        for journey in journeys:
            for v, rows in fresh.items():
                mine = [r for r in rows if r["journey"] == journey]
                n_signs = [r["n_signs"] for r in mine]
                lines.append(f"| {journey} | {v} | {min(n_signs)}-{max(n_signs)} | "
                             + " | ".join(f"{np.mean([r[m] for r in mine]):.3f}"
                                          for m in METRICS) + " |")
    return "\n".join(lines)


def run(name: str, draws: int, variants: list[str], cache_dir: Path,
        seeds: list[int] | None = None) -> str:
    from bench.corpus.run import pipeline_config
    from bench.studies.turn_detection import parse_variant

    if draws < 2:
        raise ValueError("give at least 2 draws")
    configs: dict[str, dict] = {"defaults": {}}
    for text in variants:
        v, knobs = parse_variant(text)
        pipeline_config(knobs)  # a bad knob fails now, not after the first reconstruction
        configs[v] = knobs  # strings: the config's validation converts them
    specs = [suite_spec(name, s) for s in seeds] if seeds else [suite_spec(name)]
    return table(name, {v: [row for spec in specs
                            for row in draws_of_variant(spec, draws, knobs, cache_dir)]
                        for v, knobs in configs.items()})


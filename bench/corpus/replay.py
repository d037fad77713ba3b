"""Keep each corpus journey's reconstruction, and run only the georeferencing stages on it again.

Choosing an alignment or placement knob on the corpus's tuning half costs a full run per value
(about 30 min for a half of 32 journeys with true cameras), nearly all of it ego-motion (and
calibration), which those knobs do not touch. ``signmap bench corpus --keep-reconstructions DIR``
pickles, per journey, what ``app.pipeline.run.reconstruct`` returned (or the error that ended
it) with the journey and the configuration it ran with; ``--replay DIR`` then runs
``app.pipeline.run.georeference`` on it with this run's knobs, in seconds per journey, and records
it as a full run would.

A replay gives exactly what a full run with the same knobs gives, as long as the knobs it changes
act only after ego-motion: ``GEOREF_KNOBS``. Any other knob differing from the kept run's is
refused by name, since its effect would silently be missing.
"""

from __future__ import annotations

import pickle
import time
from pathlib import Path

from app.pipeline.config import PipelineConfig
from app.pipeline.run import georeference
from app.pipeline.types import PipelineError

# PipelineConfig knobs read only by the align and triangulate stages (``georeference``). Knobs
# read earlier too are not here: min_track_frames (the plan), sign_window_margin_frames (the ego
# windows), gps_smoothing (the positions kept), gps_sigma_m (ego-motion's pose priors).
GEOREF_KNOBS = frozenset({
    "alignment", "short_alignment_min_frames", "short_alignment_margin_frames",
    "local_alignment_weight", "alignment_joint",
    "alignment_unlink_broken", "alignment_mend_broken", "gps_dropout_gap_factor",
    "max_reprojection_rms_px", "min_inlier_share", "max_sign_std_m", "min_ray_angle_deg",
    "max_alignment_rms_gps_ratio", "min_alignment_rms_reject_m", "merge_fragments_within_m",
    "sign_georef_floor_m", "sign_georef_noise_gain", "sign_georef_bias_quad_per_m",
    "antenna_offset_max_sigma_m",
})


def path_for(directory: Path, label: str) -> Path:
    return Path(directory) / f"{label}.pkl"


def differing_knobs(kept: dict, config: PipelineConfig) -> list[str]:
    """Knobs of ``config`` that differ from the kept run's and act before georeferencing."""
    now = config.model_dump()
    return sorted(k for k in now if k not in GEOREF_KNOBS and now[k] != kept.get(k))


def load(path: Path) -> dict:
    """What ``bench.paper.run_pipeline.keep`` wrote at ``path``: config (a dict), journey, recon
    (or None), error."""
    with Path(path).open("rb") as f:
        return pickle.load(f)  # noqa: S301 - our own bench's files


def replay(path: Path, config: PipelineConfig):
    """(journey, result or None, error or None, seconds) of georeferencing the kept
    reconstruction at ``path`` with ``config``. Raises ValueError when ``config`` changes a knob
    that acts before georeferencing, FileNotFoundError when nothing was kept for the journey."""
    kept = load(path)
    differs = differing_knobs(kept["config"], config)
    if differs:
        raise ValueError(f"{', '.join(differs)} act before the align stage: a replay of "
                         f"{path.name} cannot change them (run the corpus again)")
    journey = kept["journey"]
    if kept["recon"] is None:
        return journey, None, kept["error"], 0.0
    t0 = time.perf_counter()
    try:
        result = georeference(journey, kept["recon"], config)
    except PipelineError as exc:
        return journey, None, str(exc), time.perf_counter() - t0
    return journey, result, None, time.perf_counter() - t0

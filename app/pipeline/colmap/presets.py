"""Every COLMAP option the pipeline sets, as named presets (hloc's ``confs``), and the knobs of
``PipelineConfig`` that COLMAP work takes, grouped by what they are for.

A preset maps pycolmap option names (dotted for nested options, e.g. ``mapper.random_seed``) to
values; ``options(pycolmap, "IncrementalPipelineOptions", PRESET, **knobs)`` builds the pycolmap
object from a preset plus the values that come from the knobs or the window. Values that need
pycolmap itself (enums) are given as functions of the pycolmap module.

Presets: ``IMAGE_READER`` and ``SEQUENTIAL_PAIRING`` (SIFT front end); ``VERIFY_KNOWN_CAMERA`` and
``VERIFY_UNKNOWN_CAMERA`` (two-view verification of imported KLT matches); ``CALIBRATION_MAPPER``
(free intrinsics, self-calibration's stage 1) and ``EGO_MOTION_MAPPER`` (intrinsics fixed at the
calibration); ``INTRINSICS_BUNDLE_ADJUSTMENT`` (self-calibration's stage 2, ``refine``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, kw_only=True)
class SiftOptions:
    """COLMAP's SIFT extraction and sequential matching (``PipelineConfig`` documents each)."""

    max_features: int = 2048
    max_image_size: int = 1600
    first_octave: int = 0
    overlap: int = 6  # sequential matching: temporal neighbours per frame
    extractor: str = "colmap"  # or "opencv" (``cv_sift``: the full-size frame, octave -1)


@dataclass(frozen=True, kw_only=True)
class MappingOptions:
    """COLMAP's incremental mapping and bundle adjustments."""

    ba_max_refinements: int = 1
    ba_function_tolerance: float = 1e-6
    aspect_prior_sigma: float = 0.0  # stage 2: prior fx = fy with this relative sigma (0: none)
    stage1_k2: bool = False  # stage 1 maps with k1 and k2 (COLMAP RADIAL), not k1 alone
    stage2_max_iterations: int = 1000  # Ceres iterations each of stage 2's adjustments may take
    stage2_probe: float = 0.03  # stage 2 again from fx x (1 +- this) when it fits better (0: off)
    stage2_probe_points: int = 1500  # points the probe's deciding fits see


@dataclass(frozen=True, kw_only=True)
class ProcessOptions:
    """How much of the machine COLMAP may use."""

    threads: int = 2  # per process; 0 = all
    map_workers: int = 2  # processes mapping windows side by side


# --- SIFT front end (``sfm._extract_and_match``) --------------------------------------------------

# One SIMPLE_RADIAL camera for the whole journey (``CameraMode.SINGLE``); a window with a known or
# starting camera gets it written into its own copy of the database.
IMAGE_READER = {"camera_model": "SIMPLE_RADIAL"}

SEQUENTIAL_PAIRING = {
    "quadratic_overlap": False,
    "loop_detection": False,  # needs a vocabulary file it would try to download
}


def sift_extraction(sift: SiftOptions, process: ProcessOptions) -> dict[str, Any]:
    return {"num_threads": process.threads, "max_image_size": sift.max_image_size,
            "sift.max_num_features": sift.max_features, "sift.first_octave": sift.first_octave}


# --- two-view verification of imported KLT matches (``sfm._import_and_verify``) -----------------

# KLT positions are sub-pixel and consistent along a track: with the lens known, a tighter gate
# than SIFT's 4 px keeps drifted tracks out of the mapper. Unknown, the epipolar model ignores the
# distortion and needs the slack.
VERIFY_KNOWN_CAMERA = {"ransac.max_error": 2.0}
VERIFY_UNKNOWN_CAMERA = {"ransac.max_error": 4.0}


# --- incremental mapping of a window (``sfm._map_window``) --------------------------------------

_MAPPER = {
    "max_num_models": 3,
    "extract_colors": False,
    # Global BA less often than COLMAP's default (every 10 % growth): windows are short and
    # local BA keeps them consistent; measured ~20 % faster with the same result.
    "ba_global_frames_ratio": 1.5,
    "ba_global_points_ratio": 1.5,
    "random_seed": 0,
    "mapper.random_seed": 0,
    "ba_refine_principal_point": False,
}

# Intrinsics free (self-calibration's stage 1: one focal length, centred principal point, k1).
CALIBRATION_MAPPER = {
    **_MAPPER,
    # Free-intrinsics mapping sometimes starts from a pair that drifts f and k1 away, registers a
    # few images and stops; the next model, from the images left, is then usually right (22 of
    # 22 images after a 4-image model with f = 30396 px, issue 11).
    "multiple_models": True,
    "ba_refine_focal_length": True,
    "ba_refine_extra_params": True,
    "mapper.abs_pose_refine_focal_length": True,
    "mapper.abs_pose_refine_extra_params": True,
}

# Intrinsics held at the calibration (ego-motion).
EGO_MOTION_MAPPER = {
    **_MAPPER,
    "multiple_models": False,  # fixed intrinsics need one model
    "ba_refine_focal_length": False,
    "ba_refine_extra_params": False,
    "mapper.abs_pose_refine_focal_length": False,
    "mapper.abs_pose_refine_extra_params": False,
    # With known intrinsics an essential matrix fixes forward motion well, and a car on a
    # straight road moves only forwards: COLMAP's defaults (<= 0.95 forward, >= 16 deg) would
    # refuse every initial pair there.
    "mapper.init_max_forward_motion": 1.0,
    "mapper.init_min_tri_angle": 4.0,
}


# COLMAP tries a given initial pair as often as it would try pairs of its own choosing (200
# times): a pair too close for the angle it needs fails every time, 14 s on one core (c0114's
# first window, four chosen pairs, 79 s to fail). Its own choice keeps the 200: each trial is
# another pair (docs/decisions/ego-init-pair-trials.md).
CHOSEN_INIT_PAIR_TRIALS = 3


def mapper_knobs(mapping: MappingOptions) -> dict[str, Any]:
    # COLMAP re-runs every bundle adjustment after filtering outliers up to 5 (global) / 2 (local)
    # times; on our short windows the re-runs doubled the mapping time (turn-70), and
    # calibration and sign errors stayed within the tests' and the quick bench's bars without them.
    return {"ba_global_max_refinements": mapping.ba_max_refinements,
            "ba_local_max_refinements": mapping.ba_max_refinements,
            "ba_local_function_tolerance": mapping.ba_function_tolerance,
            "ba_global_function_tolerance": mapping.ba_function_tolerance}


# --- self-calibration's stage 2 (``refine._bundle_adjust``) -------------------------------------

INTRINSICS_BUNDLE_ADJUSTMENT = {
    "refine_focal_length": True,
    "refine_extra_params": True,
    "print_summary": False,
    "ceres.loss_function_type": lambda pycolmap: pycolmap.LossFunctionType.CAUCHY,
}


def options(pycolmap, kind: str, preset: dict[str, Any], **values: Any):
    """A new ``pycolmap.<kind>`` with ``preset`` and then ``values`` set (dotted names reach
    nested options; a callable value is called with the pycolmap module)."""
    out = getattr(pycolmap, kind)()
    for name, value in {**preset, **values}.items():
        *path, attr = name.split(".")
        target = out
        for part in path:
            target = getattr(target, part)
        setattr(target, attr, value(pycolmap) if callable(value) else value)
    return out

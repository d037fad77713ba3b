"""Knobs of map fusion and change detection; every threshold has a default (see the module
docstrings of ``app.fusion.fuse`` and ``app.fusion.changes`` for how they are used)."""

from __future__ import annotations

from pydantic import BaseModel, Field


class FusionConfig(BaseModel):
    # Inputs.
    cov_floor_std_m: float = Field(
        0.2, description="smallest 1-sigma per axis: overconfident signs still associate")
    unknown_alt_std_m: float = Field(
        100.0, description="vertical 1-sigma given to a sign without altitude")
    journey_abs_std_m: float = Field(
        1.0, description="horizontal 1-sigma of a journey's GPS alignment, shared by all its signs "
                         "and absent from triangulation covariances (the paper: 0.26 m relative, "
                         "1.38 m absolute)")
    journey_abs_up_std_m: float = Field(1.5, description="the same, vertically")

    # Association (journey sign <-> map sign).
    require_same_class: bool = True
    gate_chi2: float = Field(16.27, description="Mahalanobis^2 gate, chi-square 3 dof at 99.9 %")
    gate_m: float = Field(3.0, description="metric gate on the distance to the map sign")

    # Robust fused position: IRLS, Huber then Cauchy on the Mahalanobis residual.
    huber_k: float = 3.0
    cauchy_c: float = 3.0
    irls_max_iter: int = 50
    outlier_weight: float = Field(0.1, description="members weighted below this are reported")

    # Journey bias (a constant GPS offset of a whole journey).
    bias_search_m: float = Field(25.0, description="wide gate for same-class candidate pairs")
    bias_consistency_m: float = Field(
        1.5, description="candidate offsets within this of each other agree")
    bias_min_matches: int = Field(2, description="consistent sign pairs behind a pairwise offset")
    bias_min_journeys: int = Field(2, description="other journeys that must agree on an offset")
    bias_min_offset_m: float = 1.0
    bias_min_sigmas: float = 3.0
    biased_weight: float = Field(
        1e-3, description="relative weight of a flagged journey's signs in fused positions")

    # Change detection.
    view_min_depth_m: float = 4.0
    view_max_depth_m: float = 35.0
    view_margin_px: float = Field(10.0, description="a sign projecting closer to the border is out")
    min_frames_in_view: int = Field(3, description="frames in view for a journey to count as a pass")
    removal_journeys: int = Field(
        3, description="K: the last K passes all missing a sign make it possibly_removed")
    new_min_prior_misses: int = Field(
        2, description="passes that missed a sign before it first appeared make it new")
    sign_above_camera_m: float = Field(
        1.0, description="height assumed above the nearest camera for a sign without altitude")

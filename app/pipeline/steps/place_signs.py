"""The triangulate stage: one placed sign (or the reason it cannot be placed) per track id.

A track may have several passes (the car came by twice); each pass is triangulated from the
aligned poses of its own frames, and the passes that succeed are combined. Frames: ``world`` and
``enu`` are the journey's ENU frame (metres), as in ``app.pipeline.geometry.triangulation``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.pipeline.config import PipelineConfig
from app.pipeline.geometry import geodesy, gps_noise
from app.pipeline.geometry.facing import facing_deg
from app.pipeline.geometry.triangulation import (TriangulatedPoint, TriangulationError,
                                                 largest_std_m, triangulate_inliers,
                                                 undistort_pixels)
from app.pipeline.geometry.uncertainty import (GeorefTerms, georef_floor_m,
                                               horizontal_radius_m)
from app.pipeline.steps import align
from app.pipeline.types import (CameraModel, Journey, RejectedSign, Sign, SignObservation,
                                SignUncertainty, StageReport)


@dataclass(frozen=True)
class PlacedPass:
    """One pass of a track, triangulated: ``T_world_cam`` (M, 4, 4) and ``frame_idx`` (M,) of the
    frames it used; ``georef`` what its window alignment adds to its error."""

    point: TriangulatedPoint
    T_world_cam: np.ndarray
    frame_idx: np.ndarray
    alignment_rms_m: float
    georef: GeorefTerms


@dataclass
class TrackOutcome:
    """What became of a track's passes: those placed, and why the others could not be."""

    placed: list[PlacedPass] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)


def place_signs(tracks, aligned, xyz_gps: np.ndarray, camera: CameraModel, journey: Journey,
                origin: geodesy.LocalFrame, config: PipelineConfig,
                trusted: np.ndarray | None = None) -> tuple[list[Sign], list[RejectedSign]]:
    """Every track placed (a sign) or refused with its reasons. ``trusted`` (N,) bool: the
    frames whose GPS position may align the frames around a sign (``align.track_poses``)."""
    outcomes: dict[str, TrackOutcome] = {}
    classes = {t.track_id: t.cls for t in tracks}  # the passes of a track share its class
    noise_m = judging_noise_m(journey)
    for track in tracks:
        outcome = outcomes.setdefault(track.track_id, TrackOutcome())
        try:
            outcome.placed.append(place_pass(track, aligned, xyz_gps, camera, config, noise_m,
                                             trusted))
        except TriangulationError as exc:
            outcome.reasons.append(exc.reason)
    outcomes = merge_fragments(outcomes, classes, config.merge_fragments_within_m)
    signs: list[Sign] = []
    rejected: list[RejectedSign] = []
    for track_id, outcome in outcomes.items():
        cls = classes[track_id]
        placed = outcome.placed
        if not placed:
            rejected.append(RejectedSign(track_id, cls, "; ".join(dict.fromkeys(outcome.reasons))))
            continue
        xyz, cov_tri, rms_px, georef = combine(placed)
        # The gate is on the geometry alone: GPS noise is no reason to drop a well-seen sign.
        if largest_std_m(cov_tri) > config.max_sign_std_m:
            rejected.append(RejectedSign(track_id, cls, f"uncertainty {largest_std_m(cov_tri):.2f}"
                                                        f" m > {config.max_sign_std_m} m"))
            continue
        cov_enu = cov_tri + georef.cov_m2(georef_floor_m(config.sign_georef_floor_m,
                                                         journey.gps_accuracy_m),
                                          config.sign_georef_noise_gain,
                                          bias_quad_per_m=config.sign_georef_bias_quad_per_m)
        T = np.concatenate([p.T_world_cam for p in placed])
        frame_ids = [journey.frames[i].frame_id for p in placed for i in p.frame_idx]
        p_cam = np.einsum("mji,mj->mi", T[:, :3, :3], xyz[None, :] - T[:, :3, 3])
        lat, lon, alt = origin.to_geodetic(xyz[None, :])
        signs.append(Sign(
            track_id=track_id, cls=cls, xyz_enu=xyz, lat_deg=float(lat[0]),
            lon_deg=float(lon[0]), alt_m=float(alt[0]) if journey.has_altitude else None,
            std_m=largest_std_m(cov_enu), reprojection_rms_px=rms_px,
            observations=[SignObservation(f, tuple(float(v) for v in p))
                          for f, p in zip(frame_ids, p_cam)],
            facing_deg=facing_deg(xyz, T[:, :3, 3]), cov_enu=cov_enu,
            r95_h_m=horizontal_radius_m(cov_enu),
            uncertainty=SignUncertainty(cov_triangulation_enu=cov_tri, georef=georef),
        ))
    return signs, rejected


def report(signs: list[Sign], rejected: list[RejectedSign]) -> StageReport:
    """The triangulate stage's report: how many signs were placed, and each rejected track."""
    return StageReport("triangulate", f"{len(signs)} signs placed, {len(rejected)} tracks rejected",
                       tuple(f"track {r.track_id} ({r.cls}) rejected: {r.reason}"
                             for r in rejected))


def merge_fragments(outcomes: dict[str, TrackOutcome], classes: dict[str, str],
                    within_m: float) -> dict[str, TrackOutcome]:
    """The outcomes of tracks that are one sign, joined under the id of the one seen first.

    Tracks the pipeline associates itself (a bundle without track ids) break where the detector
    missed the sign for a few frames, and each piece would be placed as a sign of its own: on the
    corpus, 7 duplicates in 173 placed signs, each within 0.6 m of its true sign. Two tracks are
    one sign when they have the same class, never share a frame (one sign gives one box per
    frame) and their placed positions lie within ``within_m`` horizontally.
    """
    ids = sorted((t for t, o in outcomes.items() if o.placed),
                 key=lambda t: min(int(p.frame_idx.min()) for p in outcomes[t].placed))
    xy = {t: combine(outcomes[t].placed)[0][:2] for t in ids}
    frames = {t: set(np.concatenate([p.frame_idx for p in outcomes[t].placed]).tolist())
              for t in ids}
    into: dict[str, str] = {}
    for k, a in enumerate(ids):
        if a in into:
            continue
        for b in ids[k + 1:]:
            if (b not in into and classes[a] == classes[b] and not frames[a] & frames[b]
                    and np.linalg.norm(xy[a] - xy[b]) <= within_m):
                into[b] = a
                frames[a] |= frames[b]
    if not into:
        return outcomes
    merged = {t: TrackOutcome(list(o.placed), list(o.reasons))
              for t, o in outcomes.items() if t not in into}
    for b, a in into.items():
        merged[a].placed += outcomes[b].placed
        merged[a].reasons += outcomes[b].reasons
    return merged


def place_pass(track, aligned, xyz_gps: np.ndarray, camera: CameraModel,
               config: PipelineConfig, gps_noise_m: float | None = None,
               trusted: np.ndarray | None = None) -> PlacedPass:
    """One pass triangulated; raises TriangulationError with the reason it cannot be placed."""
    tp = align.track_poses(track, aligned, xyz_gps, mode=config.alignment,
                           margin=config.short_alignment_margin_frames,
                           min_frames=config.short_alignment_min_frames,
                           local_weight=config.local_alignment_weight, trusted=trusted)
    if tp is None or tp.keep.sum() < 2:
        raise TriangulationError("its frames were not reconstructed")
    check_reconstruction(tp.window_rms_m, gps_noise_m, config)
    px = undistort_pixels(camera, track.px[tp.keep])
    point, used = triangulate_inliers(
        tp.T_world_cam, px, camera.K, min_ray_angle_deg=config.min_ray_angle_deg,
        max_rms_px=config.max_reprojection_rms_px, min_inlier_share=config.min_inlier_share,
        min_inliers=config.min_track_frames)
    if point.std_m > config.max_sign_std_m:
        raise TriangulationError(f"uncertainty {point.std_m:.2f} m > {config.max_sign_std_m} m")
    return PlacedPass(point, tp.T_world_cam[used], track.frame_idx[tp.keep][used],
                      tp.alignment_rms_m,
                      GeorefTerms.of_alignment(tp.alignment_rms_m, tp.alignment_n,
                                               tp.window_rms_m))


def judging_noise_m(journey: Journey) -> float | None:
    """The GPS noise a window's residual is judged against (``alignment_limit_m``): the
    journey's, or where its fixes are too few for that, an estimate from as few as
    ``gps_noise.MIN_FIXES_TO_JUDGE`` of them; None below that."""
    fixes = journey.gps_fixes
    if journey.gps_noise_m is not None or fixes is None:
        return journey.gps_noise_m
    return gps_noise.white_noise_m(fixes.timestamp_s, fixes.lat_deg, fixes.lon_deg,
                                   min_fixes=gps_noise.MIN_FIXES_TO_JUDGE)


def alignment_limit_m(gps_noise_m: float | None, config: PipelineConfig) -> float | None:
    """The GPS residual rms (m) above which a window's reconstruction is taken as broken (None:
    the GPS's noise is unknown, so no limit)."""
    if gps_noise_m is None:
        return None
    return max(config.max_alignment_rms_gps_ratio * gps_noise_m, config.min_alignment_rms_reject_m)


def check_reconstruction(alignment_rms_m: float, gps_noise_m: float | None,
                         config: PipelineConfig) -> None:
    """Raises TriangulationError when the reconstruction that poses a sign disagrees with the GPS
    by far more than the GPS scatters.

    A good window follows its fixes to 1-3 times their white noise (the bias drift and the
    interpolation between fixes add to it); on the corpus's tuning half, windows of broken
    reconstructions (COLMAP mapping that went wrong, not always the same run to run) lay 8-59
    times off, and every sign they placed was 2-15 m from the truth.
    """
    limit_m = alignment_limit_m(gps_noise_m, config)
    if limit_m is not None and alignment_rms_m > limit_m:
        raise TriangulationError(
            f"the reconstruction around it disagrees with the GPS by {alignment_rms_m:.2f} m rms, "
            f"more than {config.max_alignment_rms_gps_ratio:g} x the GPS's own noise "
            f"({gps_noise_m:.2f} m)")


def combine(placed: list[PlacedPass]) -> tuple[np.ndarray, np.ndarray, float, GeorefTerms]:
    """(xyz, cov_triangulation, rms_px, georef) of one sign from its passes: their weighted
    mean, weights 1 / (std_m^2 + alignment_rms_m^2).

    Each pass comes from its own stretch of trajectory, placed by the GPS there, whose error (the
    GPS bias over the window or chain, ~0.2-0.5 m) is not in the triangulation's covariance and
    dominates it; a full inverse-covariance mean of such passes can land outside both (measured on
    loop-300, short alignment: 0.81 m from passes 0.62 and 0.37 m off). A scalar weight keeps the
    mean between the passes.
    """
    if len(placed) == 1:
        p = placed[0]
        return p.point.xyz_world, p.point.cov_world, p.point.rms_px, p.georef
    w = np.array([1.0 / (p.point.std_m**2 + p.alignment_rms_m**2) for p in placed])
    w /= w.sum()
    xyz = sum(wi * p.point.xyz_world for wi, p in zip(w, placed))
    cov = sum(wi**2 * p.point.cov_world for wi, p in zip(w, placed))
    # Independent windows: their georeferencing errors average like the positions.
    georef = GeorefTerms(*(float(sum(wi**2 * getattr(p.georef, term) for wi, p in zip(w, placed)))
                           for term in ("averaged_noise_m2", "floor_weight", "residual_m2")))
    n = [len(p.frame_idx) for p in placed]
    rms_px = float(np.sqrt(sum(k * p.point.rms_px**2 for k, p in zip(n, placed)) / sum(n)))
    return xyz, cov, rms_px, georef

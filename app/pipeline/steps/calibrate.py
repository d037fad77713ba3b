"""Self-calibration of the unknown camera on the journey's turns (the paper's Sec. III-A).

Straight driving is a critical motion for self-calibration (depth and distortion conflate), so only
frames around the turns that RDP found on the GPS track are used. Stage 1 maps a window with one
focal length, the principal point at the image centre and k1 (COLMAP SIMPLE_RADIAL, the paper's),
or k1 and k2 (RADIAL, ``calib_stage1_k2``, the default: wide lenses' corners need k2 before stage
2 can find them); stage 2 refines fx, fy, cx, cy, k1, k2 together (``colmap.refine``).

Incremental mapping with free intrinsics is fragile on car footage: when COLMAP happens to start from
a forward-moving pair, the two-view bundle adjustment drifts the focal length and k1 away and nothing
else registers, or it settles in a wrong minimum. So several candidate windows around each turn are
tried, strongest turn first, and judged by what a wrong calibration cannot fake: nearly every frame
registered and a small stage-2 reprojection error (a wrong minimum leaves ~0.7 px, a right one
~0.2 px on sharp images). The first candidate under ``calib_accept_reprojection_px`` wins when it
stands alone (``_why_not_alone``: it turns enough and contradicts no window as sharp kept before
it); otherwise, above that error, a candidate needs a second window of other frames that lands on
the same camera. One whose fx stage 2's covariance leaves looser than ``calib_max_focal_std`` is
refused. A window that registers too few frames from the first focal guess is mapped again from
others (``calib_retry_focal_factors``, in ``colmap.sfm``, where its features already are).
Only when no ordinary candidate ended the search, a wide curve gets one window spanning all of it
(``calib_long_window_max_m``). When none calibrated, two windows of one road that agree, each
turning enough and fitting well (``calib_shared_road_max_px``), are the last resort. Anything
else is refused with every candidate's reason.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from app.pipeline.colmap.sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.similarity import scale_spread
from app.pipeline.steps.turns import TurnWindow
from app.pipeline.types import Calibration, CameraModel, NoTurnError, PipelineError

log = logging.getLogger(__name__)
STAGE = "calibrate"

# Candidate windows as offsets of their start from the turn vertex, in units of the window's span:
# centred first, then shifted towards the approach and the exit of the turn. A window centred on
# the turn is mostly rotation with little baseline, and stage 2 then fell into wrong minima
# (turn-70); a window as long as the turn's approach or exit mixes in baseline. The
# last two (ending at the vertex, starting at it) are reached only when no earlier window was
# sharp or confirmed by another: a 5 Hz journey's one right window was its fourth.
CANDIDATE_OFFSETS = (-0.5, -0.67, -0.33, -0.83, -0.17, -1.0, 0.0)


@dataclass(frozen=True)
class CalibrationWindow:
    """One candidate: ``frame_idx`` (K,) sorted journey frame indices to map, around the turn
    whose RDP vertex is frame ``vertex``. ``gps_rotation_deg``: how far the GPS track turns over
    the frames ``gps_frame_idx`` of them (``turns.chord_rotation_deg``; None: all),
    ``gps_rotation_std_deg`` its standard deviation from the GPS noise; NaN where unknown
    (``plan.gps_rotation``). ``gps_xyz_m`` (K, 3): the GPS positions of ``frame_idx``, metric
    frame (None: unknown)."""

    frame_idx: np.ndarray
    vertex: int
    gps_rotation_deg: float = float("nan")
    gps_rotation_std_deg: float = float("nan")
    gps_frame_idx: np.ndarray | None = None
    gps_xyz_m: np.ndarray | None = None

    @property
    def label(self) -> str:
        return f"frames {int(self.frame_idx[0])}-{int(self.frame_idx[-1])}"


def _spread_frames(s_m: np.ndarray, rot_deg: np.ndarray, lo_m: float, hi_m: float,
                   n_images: int, rotation_share: float) -> np.ndarray:
    """Up to ``n_images`` frames spread evenly over [lo_m, hi_m] of road by a mix of distance
    travelled and heading change (``rotation_share`` of the weight); a frame is taken once however
    long the car stands on it. By distance alone, a sharp turn taken fast fell between a few
    images 20 deg apart."""
    at_m = np.interp([lo_m, hi_m], s_m, rot_deg)
    u = (s_m - lo_m) / max(hi_m - lo_m, 1e-9)
    if rotation_share > 0 and at_m[1] - at_m[0] > 1.0:
        u = (1 - rotation_share) * u + rotation_share * (rot_deg - at_m[0]) / (at_m[1] - at_m[0])
    idx = np.clip(np.searchsorted(u, np.linspace(0.0, 1.0, n_images), side="left"),
                  0, len(s_m) - 1)
    return np.unique(idx)


def candidate_windows(turns: list[TurnWindow], s_m: np.ndarray, cfg: PipelineConfig,
                      rot_deg: np.ndarray | None = None) -> list[CalibrationWindow]:
    """Candidate windows, strongest turn first, at most ``calib_max_candidates``, then the
    whole-curve ones (``_whole_curve_windows``).

    ``s_m`` (N,): metres travelled at each frame (``turns.track_length_m``); ``rot_deg`` (N,):
    heading change accumulated up to each frame (``turns.cumulative_rotation_deg``). A window spans
    ``calib_window_m`` of road, or more where frames are so far apart that it would hold fewer
    than ``calib_window_min_frames``; its ``calib_images`` frames are spread by distance and
    heading change, not by frame count, so capture rate, speed and stops do not change what a
    window sees (a fixed 44 frames spanned 13 m at 20 Hz and 6 m/s, where only 3 of 22 images
    registered, and 105 m at 5 Hz and 12 m/s)."""
    s_m = np.asarray(s_m, float)
    rot_deg = np.zeros_like(s_m) if rot_deg is None else np.asarray(rot_deg, float)
    ranked = sorted(turns, key=lambda t: -max(abs(t.angle_deg), t.rotation_deg))
    out: list[CalibrationWindow] = []
    seen: set[tuple[int, ...]] = set()
    for offset in CANDIDATE_OFFSETS:
        for turn in ranked:
            moving = np.diff(s_m[turn.start:turn.end])
            step_m = float(np.median(moving[moving > 0])) if np.any(moving > 0) else 0.0
            span_m = min(max(cfg.calib_window_m, (cfg.calib_window_min_frames - 1) * step_m),
                         float(s_m[-1] - s_m[0]))
            window = _new_window(s_m, rot_deg, s_m[turn.vertex] + offset * span_m, span_m,
                                 cfg.calib_images, turn.vertex, cfg, seen)
            if window is not None:
                out.append(window)
    return out[: cfg.calib_max_candidates] + _whole_curve_windows(ranked, s_m, rot_deg, cfg, seen)


# A whole-curve candidate is tried only for a curve this many times longer than an ordinary window.
LONG_WINDOW_MIN_RATIO = 1.5


def _whole_curve_windows(ranked: list[TurnWindow], s_m: np.ndarray, rot_deg: np.ndarray,
                         cfg: PipelineConfig, seen: set[tuple[int, ...]]
                         ) -> list[CalibrationWindow]:
    """The last candidates (``calib_long_window_max_m``; none when 0), mapped only when no ordinary
    one ended the search: one per wide curve, centred on it and spanning all of it plus
    ``calib_window_m``, with ``calib_long_window_images`` frames. A window of fixed length sees
    35-46 deg of a 45-60 m radius turn, and stage 2 leaves its fx loose; tried first, such windows
    fell into wrong minima (docs/decisions/calib-whole-curve.md), so they come after every
    ordinary one."""
    if cfg.calib_long_window_max_m <= 0:
        return []
    out = []
    for turn in ranked:
        span_m = min(cfg.calib_window_m + turn.curve_m, cfg.calib_long_window_max_m,
                     float(s_m[-1] - s_m[0]))
        if span_m < LONG_WINDOW_MIN_RATIO * max(cfg.calib_window_m, 1e-9):
            continue  # about the ordinary span: its candidates covered this curve
        window = _new_window(s_m, rot_deg, s_m[turn.vertex] - 0.5 * span_m, span_m,
                             cfg.calib_long_window_images, turn.vertex, cfg, seen)
        if window is not None:
            out.append(window)
    return out


def _new_window(s_m: np.ndarray, rot_deg: np.ndarray, lo_m: float, span_m: float, n_images: int,
                vertex: int, cfg: PipelineConfig, seen: set[tuple[int, ...]]
                ) -> CalibrationWindow | None:
    """The candidate of ``n_images`` frames over ``span_m`` of road from ``lo_m`` (moved inside
    the journey), or None when it holds too few frames or its frames are in ``seen`` already
    (they join it)."""
    lo_m = float(np.clip(lo_m, s_m[0], s_m[-1] - span_m))
    frames = _spread_frames(s_m, rot_deg, lo_m, lo_m + span_m, n_images, cfg.calib_rotation_share)
    key = tuple(frames.tolist())
    if len(frames) < cfg.calib_min_images or key in seen:
        return None
    seen.add(key)
    return CalibrationWindow(frames, vertex)


def initial_camera(width: int, height: int, cfg: PipelineConfig,
                   hint: CameraModel | None = None) -> CameraModel:
    """Stage-1 starting point: the manifest's hint if any, else a wide dash-cam guess."""
    f = hint.fx if hint is not None else cfg.calib_initial_focal_factor * width
    return _stage1_start(width, height, f, 0.0)


def _stage1_start(width: int, height: int, f: float, k1: float) -> CameraModel:
    """What stage 1 can start from: one focal length, k1, the principal point centred as stage 1
    holds it."""
    return CameraModel(width, height, f, f, (width - 1) / 2, (height - 1) / 2, k1, 0.0)


def rotation_covered_deg(T_model_cam: np.ndarray) -> float:
    """Largest rotation of any registered camera relative to the first, degrees."""
    if len(T_model_cam) < 2:
        return 0.0
    R0 = T_model_cam[0, :3, :3]
    rel = Rotation.from_matrix(np.einsum("ji,njk->nik", R0, T_model_cam[:, :3, :3]))
    return float(np.degrees(rel.magnitude().max()))


# Pixels of real sensors are square to a few per cent. The wrong minima stage 2 falls into from a
# warped stage-1 reconstruction had fx/fy of 1.13-1.16 (turn-70) at reprojection errors
# (~0.55 px) that pass the error gate: this bound is what rejects them.
MAX_ASPECT_DEVIATION = 0.08


def _implausible(camera: CameraModel) -> str | None:
    w, h = camera.width, camera.height
    if abs(camera.fx / camera.fy - 1.0) > MAX_ASPECT_DEVIATION:
        return f"fx/fy = {camera.fx / camera.fy:.2f} is implausible"
    if not (0.1 * w < camera.fx < 10 * w):
        return f"focal length {camera.fx:.0f} px is implausible for a {w} px wide image"
    if not (0.25 * w < camera.cx < 0.75 * w and 0.25 * h < camera.cy < 0.75 * h):
        return f"principal point ({camera.cx:.0f}, {camera.cy:.0f}) is far from the image centre"
    if abs(camera.k1) > 1.5 or abs(camera.k2) > 1.5:
        return f"distortion k1={camera.k1:.2f}, k2={camera.k2:.2f} is implausible"
    return None


def _poor_fit(res: WindowResult, cfg: PipelineConfig) -> str | None:
    """Why this mapping does not hold (failed, few frames registered, large error), or None."""
    if res.error:
        return res.error
    if len(res.image_names) < cfg.calib_min_registered_ratio * res.n_input:
        return f"only {len(res.image_names)}/{res.n_input} frames registered"
    if res.reprojection_error_px > cfg.max_calib_reprojection_px:
        return f"reprojection error {res.reprojection_error_px:.2f} px"
    return None


def judge_window(res: WindowResult, cfg: PipelineConfig) -> str | None:
    """Why this candidate is unusable, or None."""
    if why := _poor_fit(res, cfg):
        return why
    rotation = rotation_covered_deg(res.T_model_cam)
    if rotation < cfg.min_turn_rotation_deg:
        return f"only {rotation:.0f} deg of rotation"
    if res.focal_std_rel > 1.0:  # a singular covariance: some direction is not pinned
        return "fx is not determined by these frames (stage 2's covariance is singular)"
    if _focal_uncertain(res, cfg):
        return (f"fx uncertain by {100 * res.focal_std_rel:.2f} % "
                f"(> {100 * cfg.calib_max_focal_std:g} %)")
    return _implausible(res.camera)


def _registered(frame_idx: np.ndarray, res: WindowResult,
                frame_names: Sequence[str]) -> list[tuple[int, int]]:
    """(k, j) for each of the journey frames ``frame_idx`` (named by ``frame_names``) that
    ``res`` registered: its place k in ``frame_idx`` and j in ``res``, in ``res``'s order."""
    at = {frame_names[i]: k for k, i in enumerate(frame_idx)}
    return [(at[name], j) for j, name in enumerate(res.image_names) if name in at]


def _rotation_where_gps_measured(window: CalibrationWindow, res: WindowResult,
                                frame_names: Sequence[str] | None) -> float:
    """The reconstruction's rotation (deg) over the frames the GPS measured
    (``window.gps_frame_idx``, named by ``frame_names``); over all registered ones where the
    window names none."""
    T_model_cam = res.T_model_cam
    if window.gps_frame_idx is not None and frame_names is not None:
        rows = _registered(window.gps_frame_idx, res, frame_names)
        T_model_cam = T_model_cam[[j for _, j in rows]]
    return rotation_covered_deg(T_model_cam)


def _turns_beyond_gps(window: CalibrationWindow, rotation: float,
                      cfg: PipelineConfig) -> str | None:
    """Why the reconstruction, turning ``rotation`` deg over the frames the GPS measured, turns
    further than the GPS allows, or None.

    A focal length far too short opens every bearing, so the window's cameras turn further than
    the car did: a narrow lens with strong barrel distortion calibrated 38 % short (k1 -0.14 for
    -0.37) at 0.18 px with every frame registered turned 68 deg where the GPS turned 44 (corpus
    seed 64; docs/decisions/calib-gps-rotation-check.md). Only the excess is a tell: a
    reconstruction may turn less than the GPS says, where noise made the track zigzag. A 3 % focal
    error turns a 60 deg window by 2 deg, which this does not resolve, and is not meant to."""
    if not (cfg.calib_gps_rotation_check and np.isfinite(window.gps_rotation_deg)
            and np.isfinite(window.gps_rotation_std_deg)):
        return None
    bound = window.gps_rotation_deg + max(cfg.calib_gps_rotation_min_slack_deg,
                                          cfg.calib_gps_rotation_sigmas
                                          * window.gps_rotation_std_deg)
    if rotation > bound:
        return (f"turns {rotation:.0f} deg where the GPS turns {window.gps_rotation_deg:.0f} "
                f"(at most {bound:.0f}): a focal length far too short does that")
    return None


def _path_scale_spread(window: CalibrationWindow, res: WindowResult,
                       frame_names: Sequence[str] | None) -> float:
    """``similarity.scale_spread`` of the registered cameras against the window's GPS (NaN where
    either is missing). Reported, not judged: as a gate at 3 it changed one tuning journey of 53
    (c0838, fx +1.87 -> +0.33 %) and no other (docs/decisions/calib-path-scale.md)."""
    if window.gps_xyz_m is None or frame_names is None or res.error:
        return float("nan")
    rows = sorted(_registered(window.frame_idx, res, frame_names))  # in travel order
    if not rows:
        return float("nan")
    c_model = res.T_model_cam[[j for _, j in rows], :3, 3]
    return scale_spread(c_model, window.gps_xyz_m[[k for k, _ in rows]])


def _focal_uncertain(res: WindowResult, cfg: PipelineConfig) -> bool:
    return bool(cfg.calib_max_focal_std) and res.focal_std_rel > cfg.calib_max_focal_std


def _why_not_alone(res: WindowResult, cfg: PipelineConfig) -> str | None:
    """Why a usable candidate cannot end the search on its own but needs another window to agree,
    or None when it can: stage 2 pins its fx, it is under the sharp-image error and it turns at
    least ``calib_alone_min_rotation_deg``."""
    if _focal_uncertain(res, cfg):
        return f"fx uncertain by {100 * res.focal_std_rel:.2f} %"
    if res.reprojection_error_px > cfg.calib_accept_reprojection_px:
        return f"above {cfg.calib_accept_reprojection_px:g} px"
    rotation = rotation_covered_deg(res.T_model_cam)
    if rotation < cfg.calib_alone_min_rotation_deg:
        return f"only {rotation:.0f} deg of rotation, under {cfg.calib_alone_min_rotation_deg:g}"
    return None


def _contradicts(res: WindowResult, kept: list[tuple[CalibrationWindow, WindowResult]],
                 cfg: PipelineConfig) -> str | None:
    """Why ``res`` may not stand alone against the candidates ``kept`` before it, or None: one of
    them fitted as sharply (under ``calib_accept_reprojection_px``, fx pinned), was kept only
    because it could not stand alone (it turned too little, say), and lands on another camera.
    Two sharp windows that disagree cannot both be right, and the search has no reason to trust
    the later one."""
    if not cfg.calib_alone_consistent:
        return None
    for window, other in kept:
        if (other.reprojection_error_px <= cfg.calib_accept_reprojection_px
                and not _focal_uncertain(other, cfg) and not _agree(other.camera, res.camera, cfg)):
            return (f"disagrees with {window.label} (fx {other.camera.fx:.0f}, "
                    f"{other.reprojection_error_px:.2f} px)")
    return None


def _agree(a: CameraModel, b: CameraModel, cfg: PipelineConfig) -> bool:
    """Whether two windows' calibrations are the same camera within what stage 2 resolves."""
    tol = cfg.calib_agreement
    return (abs(a.fx / b.fx - 1.0) <= tol and abs(a.fy / b.fy - 1.0) <= tol
            and abs(a.cx - b.cx) <= tol * a.width and abs(a.cy - b.cy) <= tol * a.width
            and abs(a.k1 - b.k1) <= max(0.02, 10 * tol * abs(a.k1)))


def _agreeing_on_shared_road(kept: list[tuple[CalibrationWindow, WindowResult]],
                             cfg: PipelineConfig) -> list[tuple[CalibrationWindow, WindowResult]]:
    """The last resort when no candidate calibrated: the two ``kept`` windows that agree with the
    lowest error, when each turns at least ``calib_alone_min_rotation_deg`` and fits under
    ``calib_shared_road_max_px``; else []. Two kept windows that agree share most of their road,
    or the search would have ended on them.

    Windows of one road are weaker witnesses than windows of two, but pairs of them turning 45 deg
    or more landed within 1 % of the lens at up to 0.43 px; the two wrong pairs (fx 10-11 % short)
    fitted at 0.49 and 0.57 px (docs/decisions/calib-shared-road.md)."""
    if not cfg.calib_shared_road_max_px:
        return []
    usable = [(w, r) for w, r in kept
              if r.reprojection_error_px <= cfg.calib_shared_road_max_px
              and not _focal_uncertain(r, cfg)
              and rotation_covered_deg(r.T_model_cam) >= cfg.calib_alone_min_rotation_deg]
    pairs = [[a, b] for i, a in enumerate(usable) for b in usable[i + 1:]
             if _agree(a[1].camera, b[1].camera, cfg)]
    return min(pairs, key=lambda p: max(g[1].reprojection_error_px for g in p), default=[])


def summary(calib: Calibration) -> str:
    """One line on a self-calibration: the window, its evidence, the camera and the fit."""
    (first, end), = calib.windows[:1] or [(0, 0)]
    c = calib.camera
    return (f"self-calibrated on frames {first}-{end - 1} ({calib.evidence}): "
            f"{calib.n_registered}/{calib.n_images} registered, "
            f"{calib.reprojection_error_px:.2f} px; fx {c.fx:.1f}, fy {c.fy:.1f}, "
            f"cx {c.cx:.1f}, cy {c.cy:.1f}, k1 {c.k1:+.3f}, k2 {c.k2:+.3f}"
            + (f" (stage 2's covariance: {spread})"
               if (spread := _spread(calib.focal_std_rel, calib.intrinsics_std)) else ""))


def _spread(focal_std_rel: float, std: tuple[float, ...]) -> str:
    """Stage 2's own standard deviations of fx and the principal point, where it gave them ("":
    none, or a singular covariance). They say which intrinsics the frames pinned down and which
    they did not. The errors measured on the corpus run larger than them, 2x in the median and
    5-10x at the 90th percentile, because the features' errors are systematic, not independent
    (docs/decisions/calib-misses.md; ``bench corpus`` records both)."""
    if not (np.isfinite(focal_std_rel) and focal_std_rel <= 1.0):
        return ""
    text = f"fx ± {100 * focal_std_rel:.2f} %"
    if len(std) >= 4 and np.all(np.isfinite(std[2:4])):
        text += f", cx ± {std[2]:.1f}, cy ± {std[3]:.1f} px"
    return text


def _trial(window: CalibrationWindow, res: WindowResult, gps_turn_deg: float,
           path_spread: float = float("nan")) -> str:
    """One candidate's line; ``gps_turn_deg``: its reconstruction's turn over the frames the GPS
    measured (``_rotation_where_gps_measured``), ``path_spread`` its ``_path_scale_spread``."""
    if res.error:
        return window.label
    spread = _spread(res.focal_std_rel, res.intrinsics_std)
    spread = f", {spread}" if spread else ""
    # A window mapped again from another focal guess says which (``calib_retry_focal_factors``).
    start = f" from fx {res.retry_focal_px:.0f}" if np.isfinite(res.retry_focal_px) else ""
    if res.probe_moves and res.unprobed_camera is not None:
        c = res.unprobed_camera
        start += (f" (stage 2 again from fx x {', x '.join(f'{m:g}' for m in res.probe_moves)};"
                  f" before: fx {c.fx:.1f}, fy {c.fy:.1f}, cx {c.cx:.1f}, cy {c.cy:.1f},"
                  f" k1 {c.k1:+.4f})")
    gps = (f" (GPS {window.gps_rotation_deg:.0f} ± {window.gps_rotation_std_deg:.1f})"
           if np.isfinite(window.gps_rotation_deg) else "")
    if gps and window.gps_frame_idx is not None and len(window.gps_frame_idx) < len(
            window.frame_idx):
        gps = (f" (GPS {window.gps_rotation_deg:.0f} ± {window.gps_rotation_std_deg:.1f} over "
               f"{len(window.gps_frame_idx)} of its frames, where it turns "
               f"{gps_turn_deg:.1f})")
    if np.isfinite(path_spread):
        gps += f", path scale x {path_spread:.2f} along it (GPS)"
    return (f"{window.label}{start}: {len(res.image_names)}/{res.n_input} registered, "
            f"{res.reprojection_error_px:.2f} px, fx {res.camera.fx:.1f}{spread}, "
            f"turns {rotation_covered_deg(res.T_model_cam):.1f} deg{gps}")


def no_turn_error(cfg: PipelineConfig, images_compared: int = 0) -> NoTurnError:
    """``images_compared``: frames the plan's image look compared (0: it did not look)."""
    seen = (f", nor did {images_compared} of its frames compared show one of >= "
            f"{cfg.turn_image_min_angle_deg:.0f} deg" if images_compared else "")
    return NoTurnError("the journey has no turn (RDP found no heading change of "
                       f">= {cfg.turn_min_angle_deg:.0f} deg on the GPS track{seen})")


# Two candidates that share more of their road than this are one piece of evidence, not two:
# the candidates shifted furthest from a centred one share half of it.
MAX_SHARED_FRACTION = 0.6


def shared_fraction(a: CalibrationWindow, b: CalibrationWindow) -> float:
    """Share of ``a``'s frame span that ``b`` spans too."""
    lo, hi = int(a.frame_idx[0]), int(a.frame_idx[-1])
    overlap = min(hi, int(b.frame_idx[-1])) - max(lo, int(b.frame_idx[0]))
    return max(overlap, 0) / max(hi - lo, 1)


@dataclass
class _Search:
    """The candidate search so far: the usable windows kept until another agrees (``good``), why
    each refused or kept one did not calibrate (``reasons``) and one line per candidate tried
    (``trials``, the stage's report)."""

    cfg: PipelineConfig
    trials: list[str]
    frame_names: Sequence[str] | None = None
    reasons: list[str] = field(default_factory=list)
    good: list[tuple[CalibrationWindow, WindowResult]] = field(default_factory=list)

    def judge(self, window: CalibrationWindow, res: WindowResult) -> _Chosen | None:
        """The windows and evidence that end the search with ``res``, or None: it was refused, or
        kept until another window agrees."""
        cfg = self.cfg
        gps_turn_deg = _rotation_where_gps_measured(window, res, self.frame_names)
        trial = _trial(window, res, gps_turn_deg,
                       _path_scale_spread(window, res, self.frame_names))
        why = judge_window(res, cfg) or _turns_beyond_gps(window, gps_turn_deg, cfg)
        log.info("calibration candidate %s: %s", window.label,
                 why or f"ok, {res.reprojection_error_px:.3f} px, {res.camera.params()}")
        if why:
            self.reasons.append(f"{window.label}: {why}")
            self.trials.append(f"{trial}: refused, {why}")
            return None
        weak = _why_not_alone(res, cfg) or _contradicts(res, self.good, cfg)
        if weak is None:
            self.trials.append(f"{trial}: accepted, under {cfg.calib_accept_reprojection_px:g} px")
            return [(window, res)], "reprojection"
        # Two windows of other frames that land on the same camera are evidence a wrong minimum
        # cannot fake; blurred or compressed frames never reach the sharp-image error that ends
        # the search on its own. Windows sharing most of their road fell into the same wrong
        # minimum together (fx 18 % low at 0.59 px).
        agreeing = [g for g in self.good if _agree(g[1].camera, res.camera, cfg)
                    and shared_fraction(window, g[0]) <= MAX_SHARED_FRACTION]
        if agreeing:
            log.info("calibration: %s agrees with %s", window.label, agreeing[0][0].label)
            self.trials.append(f"{trial}: accepted, agrees with {agreeing[0][0].label}")
            return agreeing + [(window, res)], "agreement"
        self.good.append((window, res))
        self.trials.append(f"{trial}: {weak}, kept until another window agrees")
        self.reasons.append(f"{window.label}: {weak} and no other window agreed "
                            f"(fx {res.camera.fx:.0f}, k1 {res.camera.k1:+.2f})")
        return None

    def last_resort(self) -> _Chosen | None:
        """Two kept windows of one road that agree (``_agreeing_on_shared_road``), or None."""
        pair = _agreeing_on_shared_road(self.good, self.cfg)
        if not pair:
            return None
        (first, a), (second, b) = pair
        log.info("calibration: %s and %s agree on shared road", first.label, second.label)
        self.trials.append(
            f"{first.label} and {second.label}: accepted as a last resort, they share "
            f"{100 * shared_fraction(second, first):.0f} % of their road and agree "
            f"(fx {a.camera.fx:.0f} and {b.camera.fx:.0f}, "
            f"{a.reprojection_error_px:.2f} and {b.reprojection_error_px:.2f} px)")
        return pair, "agreement on shared road"


# The windows that ended the search and the evidence they gave ("reprojection", "agreement", ...).
_Chosen = tuple[list[tuple[CalibrationWindow, WindowResult]], str]


def self_calibrate(windows: list[CalibrationWindow], cfg: PipelineConfig,
                   map_window: Callable[[CalibrationWindow, CameraModel], WindowResult], *,
                   start: CameraModel,
                   on_candidate: Callable[[int, int, CalibrationWindow], None] | None = None,
                   trials: list[str] | None = None,
                   frame_names: Sequence[str] | None = None) -> Calibration:
    """Try the candidate ``windows`` until one calibrates well; raise PipelineError with every
    reason. ``map_window(window, start)`` maps the window's frames with free intrinsics from the
    camera ``start`` (``initial_camera``). ``on_candidate(k, total, window)`` is called before the
    k-th is mapped; ``trials``, when given, gets one line per candidate tried: its frames,
    registration, reprojection error and whether it was accepted or why not (the stage's
    report). ``frame_names``: the journey's image names, as ``map_window`` names registered
    images."""
    if not windows:
        raise no_turn_error(cfg)
    search = _Search(cfg, [] if trials is None else trials, frame_names)
    chosen = None
    for k, window in enumerate(windows):
        if on_candidate is not None:
            on_candidate(k, len(windows), window)
        if chosen := search.judge(window, map_window(window, start)):
            break
    chosen = chosen or search.last_resort()
    if not chosen:
        # A lone candidate above the sharp-image error is not accepted: a wrong minimum
        # (fx 23 % low, k1 +0.32 at 0.75 px) was the best of a 5 Hz journey's candidates
        # (tests/pipeline/calibration/test_calibration_varied.py), and a wrong calibration reused
        # for the camera is worse than none.
        raise PipelineError(STAGE, "self-calibration failed on every turn window: "
                            + "; ".join(search.reasons))
    return _calibration(*chosen)


def _calibration(chosen: list[tuple[CalibrationWindow, WindowResult]],
                 evidence: str) -> Calibration:
    """The calibration of the ``chosen`` window that fits best."""
    window, accepted = min(chosen, key=lambda g: g[1].reprojection_error_px)
    return Calibration(camera=accepted.camera, source="self", stage1=accepted.stage1_camera,
                       n_images=accepted.n_input, n_registered=len(accepted.image_names),
                       reprojection_error_px=accepted.reprojection_error_px,
                       rotation_deg=rotation_covered_deg(accepted.T_model_cam),
                       windows=[(int(window.frame_idx[0]), int(window.frame_idx[-1]) + 1)],
                       evidence=evidence,
                       focal_std_rel=accepted.focal_std_rel,
                       intrinsics_std=accepted.intrinsics_std,
                       observations=accepted.observations)

"""A camera's calibration from all of its journeys: one bundle adjustment over their accepted
turn windows with the intrinsics shared (issue 66, item 1; the adjustment is ``colmap.joint``).

One window's turn holds too little independent evidence to pin a camera to 1 %: its features'
small systematic errors are its own, and a wrong minimum looks right from inside it. Windows of
other journeys (other days, roads, speeds) err independently, so the camera they share is found
by adjusting them together, each keeping its own poses and points.

A wrong window must not pull the others: the windows are first grouped by what each calibrated
alone, the largest group agreeing within ``agree_rel`` (in fx and fy) is fitted, and a window
whose own calibration is beyond ``agree_rel`` of the joint result is left out and named, and the
rest fitted again. The sigma of the result is the larger of the joint covariance's (which
assumes independent pixel noise, and so claims too much) and the spread of the windows' own
calibrations over sqrt(n) (what independent windows really give).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from app.pipeline.colmap.joint import JointFit, fit_jointly
from app.pipeline.types import INTRINSICS_STD, CameraModel, WindowObservations

# A camera whose fy sigma is above this share of fy (at 2 sigma) has its pixel aspect unresolved:
# turns about one vertical axis leave fy weakly determined (issue 66's 0.3 % bar).
FY_RESOLVED_REL = 0.003


@dataclass(frozen=True)
class CameraWindow:
    """One journey's accepted calibration window: ``camera`` what it calibrated alone, with
    stage 2's ``intrinsics_std`` (6,) of ``types.INTRINSICS_STD`` (() unknown)."""

    journey: str
    camera: CameraModel
    observations: WindowObservations
    intrinsics_std: tuple[float, ...] = ()


@dataclass(frozen=True)
class JointCalibration:
    """The camera all its journeys' windows fit; ``sigma`` of each of ``INTRINSICS_STD`` (px for
    fx, fy, cx, cy; nan: not known); ``used`` the journeys fitted; ``left_out`` journey -> why;
    ``rms_px`` journey -> its window's RMS reprojection error under the result."""

    camera: CameraModel
    sigma: dict[str, float]
    used: list[str]
    left_out: dict[str, str] = field(default_factory=dict)
    rms_px: dict[str, float] = field(default_factory=dict)

    @property
    def fy_resolved(self) -> bool:
        s = self.sigma.get("fy", float("nan"))
        return bool(np.isfinite(s) and 2.0 * s <= FY_RESOLVED_REL * self.camera.fy)


Fit = Callable[[list[WindowObservations], CameraModel], JointFit]


def _vector(camera: CameraModel) -> np.ndarray:
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.k1, camera.k2])


def _camera(like: CameraModel, v: np.ndarray) -> CameraModel:
    return CameraModel(like.width, like.height, *map(float, v))


def _differs(camera: CameraModel, reference: CameraModel, agree_rel: float) -> float | None:
    """The larger relative fx or fy difference when beyond ``agree_rel``, else None."""
    d = max(abs(camera.fx / reference.fx - 1.0), abs(camera.fy / reference.fy - 1.0))
    return d if d > agree_rel else None


def largest_agreeing(windows: list[CameraWindow], agree_rel: float) -> list[int]:
    """Indices of the largest group of ``windows`` whose own calibrations lie within
    ``agree_rel`` of one member's (ties: the group of the oldest, so a camera's calibration
    does not flip between two equal camps as journeys arrive)."""
    best: list[int] = []
    for i, w in enumerate(windows):
        group = [j for j, v in enumerate(windows)
                 if _differs(v.camera, w.camera, agree_rel) is None]
        if len(group) > len(best):
            best = group
    return best


def calibrate_jointly(windows: list[CameraWindow], *, agree_rel: float = 0.03,
                      fit: Fit = fit_jointly) -> JointCalibration:
    """The camera of ``windows`` (one camera, one image size). One window is its own
    calibration, with its own sigma."""
    if not windows:
        raise ValueError("no window to calibrate from")
    sizes = {(w.camera.width, w.camera.height) for w in windows}
    if len(sizes) > 1:
        raise ValueError(f"windows of different image sizes {sorted(sizes)}: not one camera")
    left_out: dict[str, str] = {}
    group = largest_agreeing(windows, agree_rel)
    for i, w in enumerate(windows):
        if i not in group:
            left_out[w.journey] = (f"its own calibration (fx {w.camera.fx:.1f} px) disagrees with "
                                   f"the {len(group)} that agree")
    for _ in range(2):  # fit, leave out what the fit shows off, fit again
        members = [windows[i] for i in group]
        result = _fit_members(members, fit)
        moved = [i for i in group
                 if _differs(windows[i].camera, result.camera, agree_rel) is not None]
        if not moved or len(moved) == len(group):
            break
        for i in moved:
            d = _differs(windows[i].camera, result.camera, agree_rel)
            left_out[windows[i].journey] = (f"its own calibration is {100 * d:.1f} % from the "
                                            f"joint one")
        group = [i for i in group if i not in moved]
    return JointCalibration(result.camera, result.sigma, result.used, left_out, result.rms_px)


def _fit_members(members: list[CameraWindow], fit: Fit) -> JointCalibration:
    own = np.array([_vector(w.camera) for w in members])  # (n, 6)
    if len(members) == 1:
        std = np.asarray(members[0].intrinsics_std or [np.nan] * 6, float)
        return JointCalibration(members[0].camera, dict(zip(INTRINSICS_STD, map(float, std))),
                                [members[0].journey])
    start = _camera(members[0].camera, np.median(own, axis=0))
    joint = fit([w.observations for w in members], start)
    spread = own.std(axis=0, ddof=1) / np.sqrt(len(members))
    std = np.fmax(np.nan_to_num(joint.intrinsics_std, nan=0.0), spread)
    return JointCalibration(joint.camera, dict(zip(INTRINSICS_STD, map(float, std))),
                            [w.journey for w in members],
                            rms_px={w.journey: float(r) for w, r in zip(members, joint.rms_px)})

"""A stored calibration checked on a journey's turn, instead of self-calibrating again.

A camera calibrated before (jointly over its journeys' turns, or registered by its operator) is
more precise than one journey's self-calibration (0.1-0.3 % in fx against about 1 %), so a later
journey of it has no use for its own, only for knowing that the lens is still the one calibrated.
Its strongest turn's first candidate window is mapped with the stored intrinsics held: no
free-intrinsics mapping, no retries from other focal lengths, pairs verified with the known
camera (the slow and fragile parts of self-calibration). Stage 2 then frees all six intrinsics
from there, which gives the window's own estimate and a window the camera's joint fit can use: a
checked turn still refines the camera.

When the window registers, fits, and its own estimate is within ``camera_check_max_rel`` of the
stored camera (the service's tolerance for one camera), the journey uses the stored camera. Any
other outcome (another lens, a wrong stored calibration, a window that did not map) is not a
verdict on the lens: the journey self-calibrates as a new camera does, from the features the check
extracted, and the service's lens-change rule judges what it finds.
"""

from __future__ import annotations

from dataclasses import dataclass

from app.pipeline.colmap.sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.steps.calibrate import CalibrationWindow, rotation_covered_deg
from app.pipeline.types import Calibration, CameraModel

SOURCE = "checked"  # ``Calibration.source`` of a journey that used its checked camera


# What ``deviation``'s principal-point shares are of, as a report says them.
SHARE_OF = {"cx": " of the width", "cy": " of the height"}


def deviation(camera: CameraModel, reference: CameraModel) -> dict[str, float]:
    """How far ``camera`` is from ``reference``: fx and fy relative to ``reference``'s, cx and cy
    relative to its image width and height."""
    return {"fx": abs(camera.fx - reference.fx) / reference.fx,
            "fy": abs(camera.fy - reference.fy) / reference.fy,
            "cx": abs(camera.cx - reference.cx) / reference.width,
            "cy": abs(camera.cy - reference.cy) / reference.height}


@dataclass(frozen=True)
class CameraCheck:
    """The check of ``stored`` on one window: ``measured`` the window's own stage-2 camera (None:
    it did not map), ``deviation`` of it from ``stored`` (``deviation``), ``why_not`` empty when
    the window confirms ``stored``, else why it does not."""

    stored: CameraModel
    window: CalibrationWindow
    result: WindowResult
    measured: CameraModel | None
    deviation: dict[str, float]
    why_not: str

    @property
    def confirmed(self) -> bool:
        return not self.why_not

    def calibration(self) -> Calibration:
        """The journey's calibration when confirmed: the stored camera, with the window kept."""
        res = self.result
        return Calibration(
            camera=self.stored, source=SOURCE, measured=self.measured,
            n_images=res.n_input, n_registered=len(res.image_names),
            reprojection_error_px=res.reprojection_error_px,
            rotation_deg=rotation_covered_deg(res.T_model_cam),
            windows=[(int(self.window.frame_idx[0]), int(self.window.frame_idx[-1]) + 1)],
            evidence="check", focal_std_rel=res.focal_std_rel,
            intrinsics_std=res.intrinsics_std, observations=res.observations)

    def summary(self) -> str:
        where, res = self.window.label, self.result
        if self.measured is None:
            return f"stored calibration not checked on {where}: {self.why_not}"
        told = (f"{len(res.image_names)}/{res.n_input} registered, "
                f"{res.reprojection_error_px:.2f} px, its own fx {self.measured.fx:.1f}")
        if self.confirmed:
            worst = max(self.deviation, key=self.deviation.get)
            return (f"stored calibration confirmed on {where} ({told}; largest difference "
                    f"{worst} {100 * self.deviation[worst]:.2f} %{SHARE_OF.get(worst, '')})")
        return f"stored calibration not confirmed on {where}: {self.why_not} ({told})"


def judge(stored: CameraModel, window: CalibrationWindow, result: WindowResult,
          cfg: PipelineConfig) -> CameraCheck:
    """Whether ``result``, ``window`` mapped with ``stored`` held and refined by stage 2,
    confirms ``stored``."""
    registered = len(result.image_names)
    measured = result.camera if not result.error and registered else None
    dev = deviation(measured, stored) if measured is not None else {}
    if result.error:
        why = result.error
    elif registered < cfg.calib_min_registered_ratio * result.n_input:
        why = f"only {registered}/{result.n_input} frames registered"
    elif result.reprojection_error_px > cfg.max_calib_reprojection_px:
        why = f"reprojection error {result.reprojection_error_px:.2f} px"
    elif (rotation := rotation_covered_deg(result.T_model_cam)) < cfg.min_turn_rotation_deg:
        why = f"only {rotation:.0f} deg of rotation: too little to tell one lens from another"
    elif max(dev.values()) > cfg.camera_check_max_rel:
        worst = max(dev, key=dev.get)
        why = (f"its own estimate differs in {worst} by {100 * dev[worst]:.1f} %"
               f"{SHARE_OF.get(worst, '')} "
               f"(over {100 * cfg.camera_check_max_rel:g} %)")
    else:
        why = ""
    return CameraCheck(stored, window, result, measured, dev, why)

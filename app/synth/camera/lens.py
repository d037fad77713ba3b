"""The radial lens model r_d = r_u (1 + k1 r_u^2 + k2 r_u^4) (normalised image radii) at wide
angles: where it folds over, a robust inverse, and a camera built from a field of view.

``cv2.undistortPoints`` inverts the model by fixed-point iteration, which converges slowly far
off-axis for some strong barrel lenses: at the rim of the corpus's lenses it stops up to ~0.1 px
off after 200 iterations (it is exact for the KITTI-like lens). The renderer keeps OpenCV's answer
where it projects back within 1e-6 px and takes ``undistort_radius`` (a table plus Newton steps)
elsewhere. Beyond the fold nothing inverts the model: such lenses are refused (``lens_ok``).
"""

from __future__ import annotations

import math

import numpy as np

from app.pipeline.types import CameraModel

# A lens whose radial magnification d r_d / d r_u falls below this inside the image is refused:
# near the fold the image squeezes a wide angle into few pixels and no calibration recovers it.
MIN_RADIAL_SLOPE = 0.2
_TABLE = 4096


def distort_radius(r_u, k1: float, k2: float) -> np.ndarray:
    r2 = np.square(r_u)
    return np.asarray(r_u) * (1.0 + k1 * r2 + k2 * r2 * r2)


def radial_slope(r_u, k1: float, k2: float) -> np.ndarray:
    """d r_d / d r_u."""
    r2 = np.square(r_u)
    return 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2


def fold_radius(k1: float, k2: float, min_slope: float = 0.0) -> float:
    """The smallest undistorted radius where the slope falls to ``min_slope`` (inf: never)."""
    # 5 k2 u^2 + 3 k1 u + (1 - min_slope) = 0 in u = r_u^2
    roots = np.roots([5.0 * k2, 3.0 * k1, 1.0 - min_slope]) if k2 else \
        (np.array([-(1.0 - min_slope) / (3.0 * k1)]) if k1 else np.array([]))
    real = [float(u.real) for u in np.atleast_1d(roots) if abs(u.imag) < 1e-12 and u.real > 0]
    return math.sqrt(min(real)) if real else math.inf


def undistort_radius(r_d, k1: float, k2: float) -> np.ndarray:
    """r_u for distorted radii ``r_d`` on the monotonic branch (clamped at the fold)."""
    r_d = np.asarray(r_d, dtype=float)
    r_top = fold_radius(k1, k2)
    need = float(np.max(r_d, initial=0.0))
    if not math.isfinite(r_top):  # monotonic everywhere: grow the table until it covers r_d
        r_top = 1.0
        while distort_radius(r_top, k1, k2) < need:
            r_top *= 2.0
    r_tab = np.linspace(0.0, r_top, _TABLE)
    r = np.interp(r_d, distort_radius(r_tab, k1, k2), r_tab)
    for _ in range(4):  # Newton polish; the table start is already within its spacing
        slope = np.maximum(radial_slope(r, k1, k2), 1e-6)
        r = np.clip(r - (distort_radius(r, k1, k2) - r_d) / slope, 0.0, r_top)
    return r


def undistort_normalized(camera: CameraModel, px: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) -> undistorted normalised coordinates (..., 2), robustly."""
    xd = (px[..., 0] - camera.cx) / camera.fx
    yd = (px[..., 1] - camera.cy) / camera.fy
    r_d = np.hypot(xd, yd)
    r_u = undistort_radius(r_d, camera.k1, camera.k2)
    scale = np.where(r_d > 0, r_u / np.where(r_d > 0, r_d, 1.0), 1.0)
    return np.stack([xd * scale, yd * scale], axis=-1)


def corner_radius_u(camera: CameraModel) -> float:
    """The largest undistorted radius of the image's corners."""
    w, h = camera.width - 1, camera.height - 1
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
    return float(np.hypot(*undistort_normalized(camera, corners).T).max())


def lens_ok(camera: CameraModel, min_slope: float = MIN_RADIAL_SLOPE) -> bool:
    """The radial model stays monotonic (with slope >= ``min_slope``) out to the image corners."""
    w, h = camera.width - 1, camera.height - 1
    xd = (np.array([0.0, w]) - camera.cx) / camera.fx
    yd = (np.array([0.0, h]) - camera.cy) / camera.fy
    r_d = float(np.hypot(np.abs(xd).max(), np.abs(yd).max()))
    r_limit = fold_radius(camera.k1, camera.k2, min_slope)
    return not math.isfinite(r_limit) or r_d < float(distort_radius(r_limit, camera.k1,
                                                                      camera.k2))


def camera_from_fov(width: int, height: int, hfov_deg: float, k1: float, k2: float,
                    cx_offset: float = 0.0, cy_offset: float = 0.0,
                    fy_ratio: float = 1.0) -> CameraModel | None:
    """The camera whose image edges, half a width left and right of the centre, see
    ``hfov_deg`` horizontally through the lens (k1, k2); offsets are fractions of width/height.
    None when the lens folds before that angle."""
    x_u = math.tan(math.radians(hfov_deg) / 2.0)
    if x_u >= fold_radius(k1, k2, MIN_RADIAL_SLOPE):
        return None
    fx = (width / 2.0) / float(distort_radius(x_u, k1, k2))
    cam = CameraModel(width=width, height=height, fx=fx, fy=fx * fy_ratio,
                      cx=(width - 1) / 2.0 + cx_offset * width,
                      cy=(height - 1) / 2.0 + cy_offset * height, k1=k1, k2=k2)
    return cam if lens_ok(cam) else None

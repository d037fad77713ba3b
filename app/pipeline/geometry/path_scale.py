"""Does a reconstruction keep one scale along its cameras' path? Compared with GPS.

A monocular reconstruction has one unknown scale; GPS measures the metres. Where the mapper
collapsed part of a window's translation (the cameras of its first half almost still, the rest
moving), no single scale fits, and the intrinsics stage 2 then pins fit that structure, not the
lens: tuning c0838, fx +1.9 %, first-third chords 0.4x and last-third 17x the middle's against
the true centres (docs/decisions/calib-path-scale.md).
"""

from __future__ import annotations

import numpy as np


def scale_spread(c_model: np.ndarray, xyz_gps_m: np.ndarray, *, n_segments: int = 3,
                 min_chord_m: float = 4.0) -> float:
    """The largest over the smallest of the model's chord / the GPS's chord over ``n_segments``
    consecutive stretches of equal GPS road length (1: one scale fits). ``c_model`` (K, 3):
    camera centres in the model frame, ``xyz_gps_m`` (K, 3): the same frames' GPS positions
    (metres), both in travel order. NaN when a stretch's GPS chord is under ``min_chord_m``
    (the car stood, or the window is too short for the GPS to say)."""
    c_model = np.asarray(c_model, dtype=float)
    xyz_gps_m = np.asarray(xyz_gps_m, dtype=float)
    if len(c_model) < n_segments + 1:
        return float("nan")
    s_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz_gps_m, axis=0), axis=1))])
    bounds = np.searchsorted(s_m, np.linspace(0.0, s_m[-1], n_segments + 1))
    bounds[-1] = len(s_m) - 1
    ratios = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        gps_m = float(np.linalg.norm(xyz_gps_m[b] - xyz_gps_m[a]))
        if b <= a or gps_m < min_chord_m:
            return float("nan")
        ratios.append(float(np.linalg.norm(c_model[b] - c_model[a])) / gps_m)
    return max(ratios) / max(min(ratios), 1e-12)

"""Which way a sign faces, from where it was seen.

Convention (owned here): ``facing_deg`` is the compass bearing, degrees clockwise from north in
[0, 360), of the horizontal direction the sign's face points to, i.e. towards the traffic that reads
it. A sign facing drivers heading north has ``facing_deg`` 180.

A detector only sees a sign's face, so every observing camera stands in front of it: the mean of the
horizontal unit vectors from the sign to those cameras points where the face does. Cameras close to a
roadside sign see it from the side and far ones from straight ahead; their mean leans towards the
road by about as much as real signs are turned towards it (a few degrees to ~15), which is why this
is used rather than the reverse of the driving direction.
"""

from __future__ import annotations

import numpy as np


def facing_deg(xyz_sign_enu: np.ndarray, centres_cam_enu: np.ndarray) -> float | None:
    """Bearing of the sign's face from ``xyz_sign_enu`` (3,) and the observing cameras' centres
    ``centres_cam_enu`` (N, 3), both metres in one ENU frame. ``None`` when the cameras do not
    agree on a side (the mean direction is shorter than a third of a unit vector, e.g. a sign seen
    from both sides)."""
    d_en = np.asarray(centres_cam_enu, float)[:, :2] - np.asarray(xyz_sign_enu, float)[:2]
    norms = np.linalg.norm(d_en, axis=1)
    d_en = d_en[norms > 1e-6] / norms[norms > 1e-6, None]
    if len(d_en) == 0:
        return None
    mean_en = d_en.mean(axis=0)
    if np.linalg.norm(mean_en) < 1.0 / 3.0:
        return None
    return bearing_deg(mean_en)


def mean_facing_deg(facings_deg, weights) -> float | None:
    """Weighted circular mean of bearings (None entries skipped); None when there are none or
    they cancel out (a sign fused from both of its sides)."""
    pairs = [(np.radians(f), float(w)) for f, w in zip(facings_deg, weights) if f is not None]
    if not pairs or sum(w for _, w in pairs) <= 0.0:
        return None
    e = sum(w * np.sin(a) for a, w in pairs)
    n = sum(w * np.cos(a) for a, w in pairs)
    if np.hypot(e, n) < 1e-6 * sum(w for _, w in pairs):
        return None
    return bearing_deg((e, n))


def bearing_deg(vector_enu: np.ndarray) -> float:
    """Compass bearing of an ENU vector's horizontal part (degrees clockwise from north)."""
    return float(np.degrees(np.arctan2(vector_enu[0], vector_enu[1])) % 360.0)


def angle_between_deg(a_deg: float, b_deg: float) -> float:
    """Unsigned difference of two bearings, in [0, 180]."""
    return float(abs((a_deg - b_deg + 180.0) % 360.0 - 180.0))

"""Compare a pipeline result with a synthetic journey's ground truth (truth.json)."""

from __future__ import annotations

import numpy as np

from app.pipeline.facing import angle_between_deg
from app.pipeline.geodesy import frame_at
from app.pipeline.types import JourneyResult

CALIB_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2")


def calibration_errors_pct(params: dict, truth: dict) -> dict[str, float]:
    """Signed % error of each calibration parameter against the true camera."""
    cam = truth["camera"]
    return {k: 100.0 * (params[k] - cam[k]) / abs(cam[k]) for k in CALIB_KEYS}


def sign_errors(result: JourneyResult, truth: dict) -> dict[str, dict[str, float]]:
    """Per sign (by track id): absolute error (m, ENU distance to the true plate centre) and
    relative error (m, mean over observing frames of the camera-frame position error)."""
    o = truth["origin"]
    enu = frame_at(o["lat"], o["lon"], o["alt_m"])
    by_track = {str(s["track_id"]): s for s in truth["signs"] if s.get("track_id") is not None}
    out = {}
    for sign in result.signs:
        t = by_track.get(sign.track_id)
        if t is None:
            continue
        est = enu.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0]
        true = np.asarray(t["xyz_enu"], dtype=float)
        true_cam = {ob["frame"]: np.array([ob["x"], ob["y"], ob["z"]]) for ob in t["observations"]}
        rel = [np.linalg.norm(np.array(ob.p_cam) - true_cam[ob.frame_id])
               for ob in sign.observations if ob.frame_id in true_cam]
        facing_err = (angle_between_deg(sign.facing_deg, t["facing_deg"])
                      if sign.facing_deg is not None and "facing_deg" in t else float("nan"))
        out[sign.track_id] = {"abs_m": float(np.linalg.norm(est - true)),
                              "rel_m": float(np.mean(rel)) if rel else float("nan"),
                              "std_m": float(sign.std_m), "facing_err_deg": facing_err}
    return out

"""Compare a pipeline result with a synthetic journey's ground truth (truth.json)."""

from __future__ import annotations

import numpy as np

from app.pipeline.geometry.facing import angle_between_deg
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import JourneyResult

CALIB_KEYS = ("fx", "fy", "cx", "cy", "k1", "k2")


def calibration_errors_pct(params: dict, truth: dict) -> dict[str, float]:
    """Signed % error of each calibration parameter against the true camera."""
    cam = truth["camera"]
    return {k: 100.0 * (params[k] - cam[k]) / abs(cam[k]) for k in CALIB_KEYS}


# A placed sign whose track is not a true sign's (the detector's false tracks, or tracks the
# pipeline associated itself when the bundle had no track ids) is matched to the nearest true sign
# within this horizontal distance; farther than that it is a false sign.
MATCH_RADIUS_M = 3.0


def match_signs(result: JourneyResult, truth: dict, radius_m: float = MATCH_RADIUS_M
                ) -> tuple[list[tuple[object, dict]], list[dict]]:
    """(matched, unmatched): each placed sign paired with its true sign (by track id when the
    track is a true sign's, else the nearest unclaimed true sign within ``radius_m``), and one
    record per placed sign left over: a false sign (no true sign near) or a duplicate (the near
    one is taken by another placed sign)."""
    enu = truth_frame(truth)
    by_track = {str(s["track_id"]): s for s in truth["signs"]
                if s.get("track_id") not in (None, "")}
    by_id = {truth_id(s): s for s in truth["signs"]}
    true_xy = {i: np.asarray(s["xyz_enu"], float)[:2] for i, s in by_id.items()}
    matched, claimed, pending = [], set(), []
    for sign in result.signs:
        t = by_track.get(sign.track_id)
        if t is not None and truth_id(t) not in claimed:
            matched.append((sign, t))
            claimed.add(truth_id(t))
        else:
            pending.append(sign)
    unmatched = []
    for sign in pending:
        xy = enu.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0][:2]
        dist = {i: float(np.linalg.norm(xy - t)) for i, t in true_xy.items()}
        free = {i: d for i, d in dist.items() if i not in claimed and d <= radius_m}
        if free:
            best = min(free, key=free.get)
            matched.append((sign, by_id[best]))
            claimed.add(best)
            continue
        nearest = min(dist.values(), default=float("inf"))
        unmatched.append({"track_id": sign.track_id, "class": sign.cls,
                          "nearest_true_m": nearest,
                          "kind": "duplicate" if nearest <= radius_m else "false"})
    return matched, unmatched


def truth_id(sign: dict) -> str:
    """A true sign's id (older truth files have only its track id)."""
    return str(sign.get("id", sign.get("track_id")))


def truth_frame(truth: dict):
    """The truth's local ENU frame (its origin), in which ``xyz_enu`` and camera poses are."""
    o = truth["origin"]
    return frame_at(o["lat"], o["lon"], o["alt_m"])


def sign_errors(result: JourneyResult, truth: dict) -> dict[str, dict[str, float]]:
    """Per placed sign matched to a true one (``match_signs``), by the placed sign's track id:
    absolute error (m, ENU distance to the true plate centre), relative error (m, mean over
    observing frames of the camera-frame position error), facing error, horizontal error against
    its own 95 % radius, and where along the journey it was seen."""
    enu = truth_frame(truth)
    s_by_frame = {f["frame"]: f["s_m"] for f in truth.get("frames", [])}
    out = {}
    for sign, t in match_signs(result, truth)[0]:
        est = enu.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0]
        true = np.asarray(t["xyz_enu"], dtype=float)
        true_cam = {ob["frame"]: np.array([ob["x"], ob["y"], ob["z"]]) for ob in t["observations"]}
        pairs = [(np.array(ob.p_cam), true_cam[ob.frame_id]) for ob in sign.observations
                 if ob.frame_id in true_cam]
        rel = [np.linalg.norm(p - q) for p, q in pairs]
        # Range and range ratio: a reconstruction scaled wrong errs along the ray, in proportion
        # to the range; triangulation noise errs across it too.
        range_m = [np.linalg.norm(q) for _, q in pairs]
        range_ratio = [np.linalg.norm(p) / np.linalg.norm(q) for p, q in pairs]
        facing_err = (angle_between_deg(sign.facing_deg, t["facing_deg"])
                      if sign.facing_deg is not None and "facing_deg" in t else float("nan"))
        h_err_m = float(np.linalg.norm((est - true)[:2]))
        s_m = [s_by_frame[ob.frame_id] for ob in sign.observations if ob.frame_id in s_by_frame]
        out[sign.track_id] = {"truth_id": truth_id(t), "abs_m": float(np.linalg.norm(est - true)),
                              "rel_m": float(np.mean(rel)) if rel else float("nan"),
                              "range_m": float(np.mean(range_m)) if rel else float("nan"),
                              "range_ratio": (float(np.median(range_ratio)) if rel
                                              else float("nan")),
                              "std_m": float(sign.std_m), "facing_err_deg": facing_err,
                              "h_err_m": h_err_m, "r95_h_m": sign.r95_h_m,
                              "within_r95": (None if sign.r95_h_m is None
                                             else bool(h_err_m <= sign.r95_h_m)),
                              # Distance along the journey where it was seen (error vs distance).
                              "s_m": float(np.mean(s_m)) if s_m else float("nan"),
                              **_uncertainty_parts(sign)}
    return out


def _uncertainty_parts(sign) -> dict:
    """The terms of the sign's covariance, so a bench can weigh them again (uncertainty knobs)."""
    u = sign.uncertainty
    if u is None:
        return {}
    return {"cov_tri_h_m2": np.round(u.cov_triangulation_enu[:2, :2], 8).tolist(),
            "georef_noise_m2": float(u.georef.averaged_noise_m2),
            "georef_floor_weight": float(u.georef.floor_weight),
            "georef_residual_m2": float(u.georef.residual_m2)}

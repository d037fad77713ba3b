"""Journey signs as arrays in one local ENU frame, in canonical order (journey_key, sign_id).

Canonical order is what makes fusion independent of the order the caller lists signs in: every
later step only ever iterates these arrays front to back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.fusion.config import FusionConfig
from app.fusion.types import JourneySign
from app.pipeline.geometry.geodesy import LocalFrame, frame_at


@dataclass(frozen=True)
class LocalSigns:
    signs: tuple[JourneySign, ...]  # canonical order; index i everywhere below
    xyz_enu: np.ndarray  # (M, 3) metres in ``frame``; up = the frame's altitude when unknown
    cov_enu: np.ndarray  # (M, 3, 3) m^2, floored; vertical variance huge when altitude unknown
    has_alt: np.ndarray  # (M,) bool
    journey_idx: np.ndarray  # (M,) int, index into ``journey_keys``
    journey_keys: tuple[str, ...]  # sorted
    frame: LocalFrame

    def __len__(self) -> int:
        return len(self.signs)


def canonical_order(signs: list[JourneySign]) -> list[JourneySign]:
    return sorted(signs, key=lambda s: (s.journey_key, s.sign_id))


def has_altitude(alt_m: float | None) -> bool:
    return alt_m is not None and math.isfinite(alt_m)


def floor_covariance(cov_enu: np.ndarray, min_std_m: float) -> np.ndarray:
    """Raise every eigenvalue of each (..., 3, 3) covariance to at least ``min_std_m``^2."""
    sym = 0.5 * (cov_enu + np.swapaxes(cov_enu, -1, -2))
    eigval, eigvec = np.linalg.eigh(sym)
    eigval = np.maximum(eigval, min_std_m ** 2)
    return (eigvec * eigval[..., None, :]) @ np.swapaxes(eigvec, -1, -2)


def to_local_signs(signs: list[JourneySign], config: FusionConfig) -> LocalSigns:
    ordered = canonical_order(signs)
    ids = [s.sign_id for s in ordered]
    if len(set(ids)) != len(ids):
        raise ValueError("sign_id values must be unique")
    if not ordered:
        return LocalSigns((), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, bool),
                          np.zeros(0, int), (), frame_at(0.0, 0.0, None))
    has_alt = np.array([has_altitude(s.alt_m) for s in ordered])
    alt_m = np.array([s.alt_m if h else np.nan for s, h in zip(ordered, has_alt)], dtype=float)
    # The median altitude puts signs without one at a plausible height (not at 0 m ellipsoidal).
    alt0_m = float(np.median(alt_m[has_alt])) if has_alt.any() else None
    frame = frame_at(ordered[0].lat_deg, ordered[0].lon_deg, alt0_m)
    lat = np.array([s.lat_deg for s in ordered], dtype=float)
    lon = np.array([s.lon_deg for s in ordered], dtype=float)
    if not (np.all(np.isfinite(lat)) and np.all(np.isfinite(lon))):
        raise ValueError("non-finite sign position")
    xyz_enu = frame.to_local(lat, lon, alt_m)

    cov = np.array([np.asarray(s.cov_enu, dtype=float) for s in ordered])
    if cov.shape != (len(ordered), 3, 3) or not np.all(np.isfinite(cov)):
        raise ValueError("cov_enu must be a finite (3, 3) matrix for every sign")
    cov[~has_alt, 2, :] = 0.0
    cov[~has_alt, :, 2] = 0.0
    cov[~has_alt, 2, 2] = config.unknown_alt_std_m ** 2
    cov = floor_covariance(cov, config.cov_floor_std_m)

    journey_keys = tuple(sorted({s.journey_key for s in ordered}))
    index = {k: i for i, k in enumerate(journey_keys)}
    journey_idx = np.array([index[s.journey_key] for s in ordered])
    return LocalSigns(tuple(ordered), xyz_enu, cov, has_alt, journey_idx, journey_keys, frame)

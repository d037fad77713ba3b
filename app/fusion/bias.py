"""Journeys whose GPS was biased: every sign of the journey is displaced by one vector b_j.

Order-independent scheme (instead of estimating b_j against the map built so far, which cannot see
a biased journey that happens to come first in canonical order):

1. For every pair of overlapping journeys (j, k), the offset d_jk = b_j - b_k: candidate pairs are
   same-class signs within ``bias_search_m`` (25 m) horizontally; the candidate difference with the
   most candidates within ``bias_consistency_m`` (1.5 m) of it wins (ties: smaller offset, then
   canonical order); its consistent set is re-centred twice on the component-wise median. At least
   ``bias_min_matches`` (2) distinct signs of j must agree, else there is no d_jk.
2. For journey j, the same consensus over its d_jk (k = other journeys): the largest group of
   mutually consistent d_jk, at least ``bias_min_journeys`` (2) strong, ties going to the offset
   nearest zero. b_j is the component-wise median of that group. Most journeys are unbiased, so a
   biased journey agrees with the others on b_j != 0 while an unbiased one finds b_j ~ 0.
3. j is flagged when |b_j| > ``bias_min_offset_m`` (1 m) and > ``bias_min_sigmas`` (3) sigma, where
   sigma combines the estimate's standard error with the ordinary GPS alignment error of a journey
   (``journey_abs_std_m``, 1 m): with the defaults, offsets beyond ~3 m.

Consistency is judged horizontally; the vertical offset is the median over pairs where both signs
have an altitude (0 when none do).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.fusion.config import FusionConfig
from app.fusion.local import LocalSigns
from app.fusion.types import JourneyBias

MAD_TO_STD = 1.4826


@dataclass(frozen=True)
class PairOffset:
    offset_enu_m: np.ndarray  # (3,) signs of journey j minus signs of journey k
    up_known: bool
    std_m: float  # 1-sigma per horizontal component
    n_matches: int

    def reversed(self) -> "PairOffset":
        return PairOffset(-self.offset_enu_m, self.up_known, self.std_m, self.n_matches)


def _consensus(values_h: np.ndarray, tol_m: float) -> np.ndarray:
    """Boolean mask of the largest group of 2-D values within ``tol_m`` of one of them."""
    support = cKDTree(values_h).query_ball_point(values_h, r=tol_m, return_length=True)
    best = np.lexsort((np.arange(len(values_h)), np.linalg.norm(values_h, axis=1), -support))[0]
    inliers = np.linalg.norm(values_h - values_h[best], axis=1) <= tol_m
    for _ in range(2):
        centre = np.median(values_h[inliers], axis=0)
        inliers = np.linalg.norm(values_h - centre, axis=1) <= tol_m
    return inliers


def pairwise_offset(local: LocalSigns, j: int, k: int, config: FusionConfig) -> PairOffset | None:
    """d_jk = b_j - b_k from same-class sign pairs, or None without enough consistent pairs."""
    idx_j = np.flatnonzero(local.journey_idx == j)
    idx_k = np.flatnonzero(local.journey_idx == k)
    xyz = local.xyz_enu
    near = cKDTree(xyz[idx_k, :2]).query_ball_point(xyz[idx_j, :2], r=config.bias_search_m)
    pairs = [(a, idx_k[b]) for a, bs in zip(idx_j, near) for b in sorted(bs)
             if local.signs[a].cls == local.signs[idx_k[b]].cls]
    if len(pairs) < config.bias_min_matches:
        return None
    a, b = np.array(pairs).T
    diff = xyz[a] - xyz[b]
    inliers = _consensus(diff[:, :2], config.bias_consistency_m)
    n = len(np.unique(a[inliers]))
    if n < config.bias_min_matches:
        return None
    a, b, diff = a[inliers], b[inliers], diff[inliers]
    offset = np.zeros(3)
    offset[:2] = np.median(diff[:, :2], axis=0)
    both_alt = local.has_alt[a] & local.has_alt[b]
    if both_alt.any():
        offset[2] = np.median(diff[both_alt, 2])
    cov_h = local.cov_enu[a][:, :2, :2] + local.cov_enu[b][:, :2, :2]
    var_model = float(np.mean(np.trace(cov_h, axis1=1, axis2=2))) / 2.0
    mad = np.median(np.abs(diff[:, :2] - offset[:2]), axis=0)
    var_spread = float(np.mean((MAD_TO_STD * mad) ** 2))
    return PairOffset(offset, bool(both_alt.any()), float(np.sqrt(max(var_model, var_spread) / n)),
                      n)


def _overlapping(local: LocalSigns, margin_m: float) -> list[tuple[int, int]]:
    boxes = []
    for j in range(len(local.journey_keys)):
        xy = local.xyz_enu[local.journey_idx == j, :2]
        boxes.append((xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m))
    return [(j, k) for j in range(len(boxes)) for k in range(j + 1, len(boxes))
            if np.all(boxes[j][0] <= boxes[k][1]) and np.all(boxes[k][0] <= boxes[j][1])]


def estimate_journey_biases(local: LocalSigns, config: FusionConfig) -> dict[str, JourneyBias]:
    """Flagged journeys (journey_key -> estimated offset); unbiased journeys are absent."""
    offsets: dict[int, list[PairOffset]] = {j: [] for j in range(len(local.journey_keys))}
    for j, k in _overlapping(local, config.bias_search_m):
        d = pairwise_offset(local, j, k, config)
        if d is not None:
            offsets[j].append(d)
            offsets[k].append(d.reversed())
    flagged: dict[str, JourneyBias] = {}
    for j, pair_offsets in offsets.items():
        if len(pair_offsets) < config.bias_min_journeys:
            continue
        values = np.array([d.offset_enu_m for d in pair_offsets])
        group = _consensus(values[:, :2], config.bias_consistency_m)
        if group.sum() < config.bias_min_journeys:
            continue
        bias = np.zeros(3)
        bias[:2] = np.median(values[group, :2], axis=0)
        up_known = np.array([d.up_known for d in pair_offsets]) & group
        if up_known.any():
            bias[2] = np.median(values[up_known, 2])
        std_m = max(d.std_m for d, g in zip(pair_offsets, group) if g)
        size_m = float(np.linalg.norm(bias))
        # Significant against the estimate's own noise AND the ordinary journey-to-journey GPS
        # spread: only an abnormal offset costs a journey its say in absolute positions.
        sigma_m = float(np.hypot(std_m, config.journey_abs_std_m))
        if size_m > config.bias_min_offset_m and size_m > config.bias_min_sigmas * sigma_m:
            key = local.journey_keys[j]
            flagged[key] = JourneyBias(
                key, (float(bias[0]), float(bias[1]), float(bias[2])), std_m, int(group.sum()),
                sum(d.n_matches for d, g in zip(pair_offsets, group) if g))
    return flagged

"""Gated, one-to-one association of a journey's signs to map signs, and the final merge pass.

Gate (both must hold): same class (``require_same_class``); distance <= ``gate_m`` (3 m; the
vertical part counts only when both have an altitude); Mahalanobis^2 under C_sign + C_map <=
``gate_chi2`` (16.27, chi-square 3 dof at 99.9 %). Covariances were floored on input, so
overconfident signs still pass. Among gated pairs, scipy's linear_sum_assignment picks the one-to-one
matching with the most pairs and then the least total Mahalanobis^2.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from app.fusion.config import FusionConfig
from app.fusion.robust import robust_fuse

INFEASIBLE = 1e6


@dataclass(frozen=True)
class Observations:
    """Journey signs in canonical order, corrected for journey bias (index i = canonical sign i)."""

    xyz_enu: np.ndarray  # (M, 3)
    cov_enu: np.ndarray  # (M, 3, 3)
    scale: np.ndarray  # (M,) relative information weight (near 0 for biased journeys)
    has_alt: np.ndarray  # (M,) bool
    cls: tuple[str, ...]
    journey_idx: np.ndarray  # (M,) int


@dataclass(frozen=True)
class Cluster:
    """A map sign under construction."""

    members: tuple[int, ...]  # canonical sign indices, ascending
    xyz_enu: np.ndarray  # (3,)
    cov_enu: np.ndarray  # (3, 3)
    has_alt: bool
    cls: str
    weights: np.ndarray  # (len(members),) robust weights

    def journeys(self, obs: Observations) -> set[int]:
        return set(obs.journey_idx[list(self.members)].tolist())


def fuse_cluster(members, obs: Observations, config: FusionConfig) -> Cluster:
    idx = sorted(members)
    fused = robust_fuse(obs.xyz_enu[idx], obs.cov_enu[idx], obs.scale[idx],
                        huber_k=config.huber_k, cauchy_c=config.cauchy_c,
                        max_iter=config.irls_max_iter)
    counts = Counter(obs.cls[i] for i in idx)
    cls = min(counts, key=lambda c: (-counts[c], c))  # majority, ties to the smallest name
    return Cluster(tuple(idx), fused.xyz_enu, fused.cov_enu, bool(obs.has_alt[idx].any()), cls,
                   fused.weights)


def gated_cost(x_a: np.ndarray, cov_a: np.ndarray, alt_a: bool, cls_a: str,
               x_b: np.ndarray, cov_b: np.ndarray, alt_b: bool, cls_b: str,
               config: FusionConfig) -> float | None:
    """Mahalanobis^2 between two uncertain positions, or None when a gate fails."""
    if config.require_same_class and cls_a != cls_b:
        return None
    d = x_a - x_b
    metric_m = np.linalg.norm(d if (alt_a and alt_b) else d[:2])
    if metric_m > config.gate_m:
        return None
    m2 = float(d @ np.linalg.solve(cov_a + cov_b, d))
    return m2 if m2 <= config.gate_chi2 else None


def associate_journey(rows: np.ndarray, clusters: list[Cluster], obs: Observations,
                      config: FusionConfig) -> list[int | None]:
    """For each sign in ``rows`` (one journey), the index of its map sign, or None for a new one."""
    assignment: list[int | None] = [None] * len(rows)
    if not clusters or len(rows) == 0:
        return assignment
    tree = cKDTree(np.array([c.xyz_enu[:2] for c in clusters]))
    near = tree.query_ball_point(obs.xyz_enu[rows, :2], r=config.gate_m)
    cols = sorted({c for cs in near for c in cs})
    if not cols:
        return assignment
    col_of = {c: n for n, c in enumerate(cols)}
    cost = np.full((len(rows), len(cols)), INFEASIBLE)
    for r, (i, cs) in enumerate(zip(rows, near)):
        for c in cs:
            m = clusters[c]
            g = gated_cost(obs.xyz_enu[i], obs.cov_enu[i], bool(obs.has_alt[i]), obs.cls[i],
                           m.xyz_enu, m.cov_enu, m.has_alt, m.cls, config)
            if g is not None:
                cost[r, col_of[c]] = g
    for r, c in zip(*linear_sum_assignment(cost)):
        if cost[r, c] < INFEASIBLE:
            assignment[r] = cols[c]
    return assignment


def merge_clusters(clusters: list[Cluster], obs: Observations,
                   config: FusionConfig) -> list[Cluster]:
    """Merge map signs that pass the gate against each other and share no journey.

    Sequential association can split one sign when its first observations were far apart; each
    round merges the closest (Mahalanobis) disjoint pairs, until none is left.
    """
    clusters = sorted(clusters, key=lambda c: c.members[0])
    while len(clusters) > 1:
        tree = cKDTree(np.array([c.xyz_enu[:2] for c in clusters]))
        candidates = []
        for a, b in sorted(tree.query_pairs(r=config.gate_m)):
            ca, cb = clusters[a], clusters[b]
            if ca.journeys(obs) & cb.journeys(obs):
                continue
            g = gated_cost(ca.xyz_enu, ca.cov_enu, ca.has_alt, ca.cls,
                           cb.xyz_enu, cb.cov_enu, cb.has_alt, cb.cls, config)
            if g is not None:
                candidates.append((g, a, b))
        if not candidates:
            break
        used: set[int] = set()
        merged = []
        for _, a, b in sorted(candidates):
            if a not in used and b not in used:
                used |= {a, b}
                merged.append(fuse_cluster(clusters[a].members + clusters[b].members, obs, config))
        kept = [c for n, c in enumerate(clusters) if n not in used]
        clusters = sorted(kept + merged, key=lambda c: c.members[0])
    return clusters

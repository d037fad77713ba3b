"""Fuse many journeys' triangulated signs into one map, deterministically.

``fuse_map`` depends only on the SET of journey signs: any input order gives the same map sign ids,
members and bit-identical positions, because every step runs over the canonical order
(journey_key, then sign_id) in one ENU frame whose origin is the first sign's lat/lon at the median
altitude. The algorithm (thresholds are ``FusionConfig`` fields, defaults in brackets):

1. Inputs: covariances floored to ``cov_floor_std_m`` [0.2 m] per axis; a sign without altitude gets
   ``unknown_alt_std_m`` [100 m] vertically, so it constrains only the horizontal position. After
   bias estimation every sign's covariance grows by its journey's GPS alignment error
   (``journey_abs_std_m`` [1 m] horizontally, ``journey_abs_up_std_m`` [1.5 m] up): triangulation
   covariances are relative to the journey's trajectory, and without this term two journeys'
   observations of one sign 1.5 m apart (typical GPS) would fail the chi-square gate.
2. Journey bias (``app.fusion.bias``): a journey whose signs all sit at one consistent offset from
   those of >= 2 other journeys, larger than 1 m and than 3 sigma (sigma includes the ordinary GPS
   spread, so ~3 m with the defaults), is flagged; its signs are associated
   after removing the offset (covariance grown by the offset's) and keep a relative weight of
   ``biased_weight`` [1e-3] in fused positions.
3. Association (``app.fusion.associate``), journeys in canonical order: each journey's signs are
   matched one-to-one to the current map signs inside the class + 3 m + chi-square(3) 99.9 % gates
   (linear_sum_assignment on Mahalanobis^2); an unmatched sign starts a new map sign. A map sign's
   position is recomputed from all its members whenever it gains one, so the final positions are
   exactly a from-scratch fit of the final memberships.
4. Merge pass: map signs that pass the same gates against each other and share no journey merge.
5. Fused position (``app.fusion.robust``): information-form mean, Huber then Cauchy IRLS on the
   Mahalanobis residuals, covariance from the final weights. Class: the members' majority (ties to
   the alphabetically first).
6. Ids: ``map_id`` = "ms-" + sha256 of the sign_id of the earliest-captured member (then smallest
   journey_key, sign_id)[:16], so an id survives new journeys being added later.

All map signs come out ``state="confirmed"``; ``app.fusion.changes.detect_changes`` sets the state
from where journeys looked.
"""

from __future__ import annotations

import hashlib

import numpy as np

from app.fusion.associate import (Cluster, Observations, associate_journey, fuse_cluster,
                                  merge_clusters)
from app.fusion.bias import estimate_journey_biases
from app.fusion.config import FusionConfig
from app.fusion.local import LocalSigns, to_local_signs
from app.fusion.types import FusionResult, JourneyBias, JourneySign, MapSign
from app.pipeline.geometry.facing import mean_facing_deg


def _corrected(local: LocalSigns, biases: dict[str, JourneyBias],
               config: FusionConfig) -> Observations:
    xyz = local.xyz_enu.copy()
    # Bias estimation compared journeys by their relative covariances; from here on a sign's
    # absolute uncertainty includes its journey's GPS alignment error.
    cov = local.cov_enu + np.diag([config.journey_abs_std_m ** 2] * 2
                                  + [config.journey_abs_up_std_m ** 2])
    scale = np.ones(len(local))
    for key, bias in biases.items():
        rows = local.journey_idx == local.journey_keys.index(key)
        offset = np.array(bias.offset_enu_m)
        xyz[rows, :2] -= offset[:2]
        xyz[rows & local.has_alt, 2] -= offset[2]
        cov[rows] += bias.std_m ** 2 * np.eye(3)
        scale[rows] = config.biased_weight
    return Observations(xyz, cov, scale, local.has_alt, tuple(s.cls for s in local.signs),
                        local.journey_idx)


def map_id_for(members: list[JourneySign]) -> str:
    seed = min(members, key=lambda s: (s.captured_at, s.journey_key, s.sign_id))
    return "ms-" + hashlib.sha256(seed.sign_id.encode()).hexdigest()[:16]


def _map_signs(clusters: list[Cluster], local: LocalSigns, biased: set[str],
               config: FusionConfig) -> list[MapSign]:
    if not clusters:
        return []
    lat, lon, alt = local.frame.to_geodetic(np.array([c.xyz_enu for c in clusters]))
    out = []
    for n, c in enumerate(clusters):
        members = [local.signs[i] for i in c.members]
        ids = [s.sign_id for s in members]
        times = [s.captured_at for s in members]
        evidence = {
            "weights": {i: float(w) for i, w in zip(ids, c.weights)},
            "outliers": sorted(i for i, w in zip(ids, c.weights) if w < config.outlier_weight),
            "biased_members": sorted(s.sign_id for s in members if s.journey_key in biased),
        }
        out.append(MapSign(
            map_id=map_id_for(members), cls=c.cls, lat_deg=float(lat[n]), lon_deg=float(lon[n]),
            alt_m=float(alt[n]) if c.has_alt else None, cov_enu=c.cov_enu, members=sorted(ids),
            journeys=sorted({s.journey_key for s in members}), n_observations=len(members),
            first_seen_at=float(min(times)), last_seen_at=float(max(times)), state="confirmed",
            evidence=evidence,
            facing_deg=mean_facing_deg([s.facing_deg for s in members], c.weights)))
    return sorted(out, key=lambda m: m.map_id)


def fuse_map(signs: list[JourneySign], *, config: FusionConfig | None = None) -> FusionResult:
    """The map (or a region of it) from scratch, from every journey's triangulated signs."""
    config = config or FusionConfig()
    local = to_local_signs(signs, config)
    frame = local.frame
    origin = (frame.lat0_deg, frame.lon0_deg, frame.alt0_m)
    if not len(local):
        return FusionResult([], {}, origin)
    biases = estimate_journey_biases(local, config)
    obs = _corrected(local, biases, config)
    clusters: list[Cluster] = []
    for j in range(len(local.journey_keys)):
        rows = np.flatnonzero(local.journey_idx == j)
        grown: dict[int, list[int]] = {}
        for i, c in zip(rows, associate_journey(rows, clusters, obs, config)):
            if c is None:
                clusters.append(fuse_cluster([int(i)], obs, config))
            else:
                grown[c] = list(clusters[c].members) + [int(i)]
        for c, members in grown.items():
            clusters[c] = fuse_cluster(members, obs, config)
    clusters = merge_clusters(clusters, obs, config)
    return FusionResult(_map_signs(clusters, local, set(biases), config), biases, origin)

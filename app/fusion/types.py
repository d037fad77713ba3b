"""Values of the map-fusion step: journey signs in, map signs out, and what a journey saw.

Positions are WGS84 degrees and ellipsoidal metres (``alt_m`` None when unknown); covariances are
(3, 3) m^2 in a local East-North-Up frame at the sign. Times are unix seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from app.pipeline.types import CameraModel

MapSignState = Literal["new", "confirmed", "possibly_removed"]


# eq=False where a field is an array: field-wise == on arrays has no single truth value.
@dataclass(frozen=True, eq=False)
class JourneySign:
    """One journey's triangulated sign."""

    sign_id: str  # unique and stable, e.g. "<journey_id>:<track_id>"
    journey_key: str  # canonical key of the journey (its bundle sha256), orders the fusion
    cls: str
    lat_deg: float
    lon_deg: float
    alt_m: float | None
    cov_enu: np.ndarray  # (3, 3) m^2, east/north/up
    captured_at: float  # unix seconds when the journey was recorded
    facing_deg: float | None = None  # compass bearing of its face (app.pipeline.geometry.facing)


@dataclass(eq=False)
class MapSign:
    """One physical sign of the map, fused from the journey signs in ``members``."""

    map_id: str
    cls: str
    lat_deg: float
    lon_deg: float
    alt_m: float | None  # None when no member had an altitude
    cov_enu: np.ndarray  # (3, 3) m^2, east/north/up
    members: list[str]  # sign_ids, sorted
    journeys: list[str]  # journey_keys of the members, sorted
    n_observations: int  # number of member journey signs (one per journey)
    first_seen_at: float
    last_seen_at: float
    state: MapSignState = "confirmed"
    evidence: dict = field(default_factory=dict)  # JSON-serialisable
    facing_deg: float | None = None  # the members' weighted circular mean


@dataclass(frozen=True)
class JourneyBias:
    """A journey whose signs are all displaced by one vector (a biased GPS), as estimated."""

    journey_key: str
    offset_enu_m: tuple[float, float, float]  # to SUBTRACT from its signs; up is 0 when unknown
    std_m: float  # 1-sigma uncertainty of each horizontal component
    n_journeys: int  # other journeys that agree on this offset
    n_matches: int  # sign pairs behind it


@dataclass
class FusionResult:
    signs: list[MapSign]  # sorted by map_id
    biased_journeys: dict[str, JourneyBias]  # journey_key -> offset, flagged journeys only
    origin_lat_lon_alt: tuple[float, float, float]  # the ENU frame the maths ran in


@dataclass(frozen=True, eq=False)
class JourneyCoverage:
    """Where one journey's camera looked, to tell an unseen sign from an undriven one."""

    journey_key: str
    captured_at: float
    T_world_cam: np.ndarray  # (N, 4, 4) aligned camera poses, world = ENU at origin_lat_lon_alt
    origin_lat_lon_alt: tuple[float, float, float]
    camera: CameraModel
    detected_sign_ids: frozenset[str] | set[str]  # the JourneySign ids this journey produced

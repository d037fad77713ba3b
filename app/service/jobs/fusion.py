"""Map fusion in the service: after a journey's signs are stored, re-fuse the region around it.

The region is the box of the journey's signs and camera track grown by ``fusion_region_margin_m``,
closed over map-sign membership (every journey sign linked to a map sign in the region, and every
map sign such a sign belongs to). It is fused from scratch with ``app.fusion.fuse_map``, judged with
``detect_changes`` against the coverage of every done journey that drove near it, and its map signs
are replaced in ONE transaction that holds the fusion lock (PostgreSQL: an advisory transaction
lock; SQLite: a process lock plus ``BEGIN IMMEDIATE``, SQLite's own write lock), so two workers
never fuse the same place from two stale views. Map signs that disappear become tombstones
(``removed_at``) for incremental clients.
"""

from __future__ import annotations

import logging
import math
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Iterator

import numpy as np
from sqlalchemy import and_, delete, select, text
from sqlalchemy.orm import Session

from app.fusion import JourneyCoverage, JourneySign, MapSign, detect_changes, fuse_map
from app.pipeline.types import CameraModel, Journey as JourneyData, JourneyResult
from app.service import storage
from app.service.db import map_rows
from app.service.jobs import state
from app.service.db.session import session_scope
from app.service.db.models import (JourneyRow, CoverageRow,
                                JourneySignRow, MapSignRow,
                                MapSignMemberRow, serves_result, utc_now)
from app.settings import Settings

log = logging.getLogger(__name__)

# pg_advisory_xact_lock key shared by every fusion transaction ("SIGNMAPF").
FUSION_LOCK_KEY = 0x5349474E4D415046
_SQLITE_FUSION_LOCK = threading.Lock()
M_PER_DEG_LAT = 111_320.0


@dataclass(frozen=True)
class Region:
    """A lat/lon box in WGS84 degrees (not crossing the antimeridian)."""

    min_lat: float
    min_lon: float
    max_lat: float
    max_lon: float

    @classmethod
    def around(cls, lat_deg, lon_deg, margin_m: float) -> "Region | None":
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        if lat.size == 0:
            return None
        dlat = margin_m / M_PER_DEG_LAT
        dlon = margin_m / (M_PER_DEG_LAT * max(0.01, math.cos(math.radians(float(lat.mean())))))
        return cls(min_lat=float(lat.min()) - dlat, min_lon=float(lon.min()) - dlon,
                   max_lat=float(lat.max()) + dlat, max_lon=float(lon.max()) + dlon)

    def contains(self, lat_col, lon_col):
        return and_(lat_col.between(self.min_lat, self.max_lat),
                    lon_col.between(self.min_lon, self.max_lon))


@dataclass(frozen=True)
class FusionSummary:
    n_journey_signs: int
    created: list[str]
    updated: list[str]
    removed: list[str]
    unchanged: int
    biased_journeys: list[str]  # journey ids


def calibration_flag(stored: CameraModel | None, result: JourneyResult, max_rel: float,
                     stored_source: str | None = None) -> dict | None:
    """Why this journey's self-calibration disagrees with the camera's stored one, or None:
    fx or fy off by more than ``max_rel`` relatively, or cx/cy by more than ``max_rel`` of the
    image width/height. ``stored_source``: 'registered' or 'consensus'
    (``state.StoredCalibration.source``), said in the flag when given."""
    calib = result.calibration
    if stored is None or calib.source != "self":
        return None
    cam = calib.camera
    deviation = state.calibration_deviation(cam, stored)
    over = sorted(k for k, v in deviation.items() if v > max_rel)
    if not over:
        return None
    which = "registered" if stored_source == "registered" else "stored"
    flag = {"reason": f"self-calibration differs from the {which} one in {', '.join(over)}",
            "relative_deviation": {k: round(v, 5) for k, v in deviation.items()},
            "threshold": max_rel, "stored": stored.params()}
    if stored_source is not None:
        flag["stored_source"] = stored_source
    return flag


def journey_key(row: JourneyRow) -> str:
    # Content first, so the canonical fusion order does not depend on random ids; the id keeps two
    # uploads of the same bytes (by two owners) apart.
    return f"{row.bundle_sha256}/{row.id}"


def captured_at_s(row: JourneyRow) -> float:
    if row.captured_at:
        try:
            when = datetime.fromisoformat(row.captured_at.replace("Z", "+00:00"))
            return (when if when.tzinfo else when.replace(tzinfo=timezone.utc)).timestamp()
        except ValueError:
            pass
    return row.created_at.timestamp()


def store_journey(session: Session, journey_id: str, attempt: int, journey: JourneyData,
                  result: JourneyResult, timings_s: dict[str, float],
                  known_camera: CameraModel | None, settings: Settings,
                  stored_source: str | None = None) -> bool:
    """In the caller's transaction: the journey's result (``state.store_result``), its coverage,
    its own antenna offset estimate and its calibration flag. False (nothing written) when this
    run no longer owns the journey."""
    if not state.store_result(session, journey_id, attempt, journey, result, timings_s,
                              lens=state.LensRule.of(settings)):
        return False
    row = session.get(JourneyRow, journey_id)
    row.antenna_estimate = (result.antenna_estimate.to_json()
                            if result.antenna_estimate is not None else None)
    row.calibration_flag = calibration_flag(known_camera, result, settings.calibration_flag_rel,
                                            stored_source)
    if row.calibration_flag:
        log.warning("journey %s: %s", journey_id, row.calibration_flag["reason"])
    session.merge(map_rows.coverage_row(row, journey_key(row), captured_at_s(row), result))
    return True


def store_and_fuse(url: str, journey_id: str, attempt: int, journey: JourneyData,
                   result: JourneyResult, timings_s: dict[str, float],
                   known_camera: CameraModel | None, settings: Settings,
                   stored_source: str | None = None) -> bool:
    """``store_journey`` and the re-fusion of the region around it in ONE transaction, so that a
    client that sees the journey done finds its signs in the map too (stored first and fused in a
    second commit, a poller could read "done" and an empty map in between). When the fusion
    fails, the journey is stored alone (logged): its signs stay, the next fusion of the place has
    them."""
    try:
        with fusion_session(url) as session:
            if not store_journey(session, journey_id, attempt, journey, result, timings_s,
                                 known_camera, settings, stored_source):
                return False
            summary = _fuse_around(session, journey_id, settings)
    except Exception:
        log.exception("journey %s: storing it with the map fusion failed; storing it alone",
                      journey_id)
        with session_scope(url) as session:
            return store_journey(session, journey_id, attempt, journey, result, timings_s,
                                 known_camera, settings, stored_source)
    if summary is not None:
        _log(f"journey {journey_id}", summary)
    return True


def _journey_region(session: Session, journey_id: str, margin_m: float) -> Region | None:
    latlon = session.execute(select(JourneySignRow.lat_deg, JourneySignRow.lon_deg)
                             .where(JourneySignRow.journey_id == journey_id)).all()
    cov = session.get(CoverageRow, journey_id)
    if cov is not None and cov.min_lat_deg is not None:
        latlon += [(cov.min_lat_deg, cov.min_lon_deg), (cov.max_lat_deg, cov.max_lon_deg)]
    return Region.around([p[0] for p in latlon], [p[1] for p in latlon], margin_m)


def _fuse_around(session: Session, journey_id: str, settings: Settings) -> FusionSummary | None:
    """Re-fuse the region around the journey; the caller holds the fusion lock."""
    region = _journey_region(session, journey_id, settings.fusion_region_margin_m)
    return fuse_region(session, region, settings) if region is not None else None


def refuse_around(url: str, journey_id: str, settings: Settings) -> FusionSummary | None:
    """Re-fuse the region around a stored journey in its own transaction (the worker's repair of
    a fusion that failed after the store)."""
    with fusion_session(url) as session:
        summary = _fuse_around(session, journey_id, settings)
    if summary is not None:
        _log(f"journey {journey_id}", summary)
    return summary


def delete_journey(url: str, journey_id: str, settings: Settings) -> bool:
    """Delete a journey with its signs and coverage and re-fuse its region, in one transaction."""
    with fusion_session(url) as session:
        if session.get(JourneyRow, journey_id) is None:
            return False
        region = _journey_region(session, journey_id, settings.fusion_region_margin_m)
        session.execute(delete(JourneyRow).where(JourneyRow.id == journey_id))
        summary = fuse_region(session, region, settings) if region is not None else None
    if summary is not None:
        _log(f"deleted journey {journey_id}", summary)
    return True


@contextmanager
def fusion_session(url: str) -> Iterator[Session]:
    """A transaction holding the fusion lock from its first statement, so that every read inside
    it already sees the previous fusion's commit."""
    if url.startswith("sqlite"):
        with _SQLITE_FUSION_LOCK, session_scope(url) as session:
            session.connection().exec_driver_sql("BEGIN IMMEDIATE")
            yield session
    else:
        with session_scope(url) as session:
            session.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": FUSION_LOCK_KEY})
            yield session


def _done_signs(session: Session, where) -> dict[str, tuple[JourneySignRow, JourneyRow]]:
    rows = session.execute(select(JourneySignRow, JourneyRow)
                           .join(JourneyRow, JourneyRow.id == JourneySignRow.journey_id)
                           .where(serves_result(), where)).all()
    return {s.id: (s, j) for s, j in rows}


def _closure(session: Session, region: Region):
    """The region's done journey signs and live map signs, closed over membership."""
    signs = _done_signs(session, region.contains(JourneySignRow.lat_deg, JourneySignRow.lon_deg))
    old = set(session.scalars(select(MapSignRow.id).where(
        MapSignRow.removed_at.is_(None), region.contains(MapSignRow.lat_deg, MapSignRow.lon_deg))))
    looked_up = set(signs)  # members of journeys not done (being re-run) are looked up once
    while True:
        linked = set(session.scalars(select(MapSignMemberRow.map_sign_id).where(
            MapSignMemberRow.journey_sign_id.in_(list(signs))))) if signs else set()
        members = set(session.scalars(select(MapSignMemberRow.journey_sign_id).where(
            MapSignMemberRow.map_sign_id.in_(list(old | linked))))) if old | linked else set()
        missing = members - looked_up
        grown = old | linked
        if not missing and grown == old:
            return signs, old
        old = grown
        if missing:
            looked_up |= missing
            signs.update(_done_signs(session, JourneySignRow.id.in_(list(missing))))


def _coverages(session: Session, signs: list[JourneySign], reach_m: float
               ) -> list[JourneyCoverage]:
    box = Region.around([s.lat_deg for s in signs], [s.lon_deg for s in signs], reach_m)
    rows = session.execute(select(CoverageRow).join(JourneyRow).where(
        serves_result(), CoverageRow.min_lat_deg <= box.max_lat,
        CoverageRow.max_lat_deg >= box.min_lat, CoverageRow.min_lon_deg <= box.max_lon,
        CoverageRow.max_lon_deg >= box.min_lon)).scalars().all()
    detected: dict[str, set[str]] = {}
    for s in signs:
        detected.setdefault(s.journey_key, set()).add(s.sign_id)
    return [map_rows.coverage(r, frozenset(detected.get(r.journey_key, ()))) for r in rows]


def fuse_region(session: Session, region: Region, settings: Settings) -> FusionSummary:
    """Replace the region's map signs by a from-scratch fusion; the caller holds the lock."""
    config = settings.fusion
    rows, old_ids = _closure(session, region)
    signs = [map_rows.journey_sign(s, journey_key(j), captured_at_s(j)) for s, j in rows.values()]
    fused = fuse_map(signs, config=config)
    coverages = _coverages(session, signs, config.view_max_depth_m) if signs else []
    judged: list[MapSign] = detect_changes(fused.signs, coverages, config=config)
    now = utc_now()
    new_ids = {m.map_id for m in judged}
    touched = sorted(old_ids | new_ids)
    existing = {r.id: r for r in session.scalars(select(MapSignRow).where(
        MapSignRow.id.in_(touched)))} if touched else {}
    if touched:
        session.execute(delete(MapSignMemberRow).where(MapSignMemberRow.map_sign_id.in_(touched)))
    created, updated, unchanged = [], [], 0
    for sign in judged:
        values = map_rows.map_sign_values(sign)
        row = existing.get(sign.map_id)
        if row is None:
            session.add(MapSignRow(id=sign.map_id, created_at=now, updated_at=now, **values))
            created.append(sign.map_id)
        else:
            changed = row.removed_at is not None or map_rows.differs(row, values)
            # Always the latest from-scratch values (so the map does not depend on its history),
            # but only a real change is announced to incremental clients.
            for key, value in values.items():
                setattr(row, key, value)
            if changed:
                row.removed_at, row.updated_at = None, now
                updated.append(sign.map_id)
            else:
                unchanged += 1
    session.flush()
    weights = {m.map_id: m.evidence.get("weights", {}) for m in judged}
    session.add_all(MapSignMemberRow(map_sign_id=m.map_id, journey_sign_id=sid,
                                  weight=float(weights[m.map_id].get(sid, 1.0)))
                    for m in judged for sid in m.members)
    removed = sorted(old_ids - new_ids)
    for map_id in removed:
        existing[map_id].removed_at = existing[map_id].updated_at = now
    id_of_key = {journey_key(j): j.id for _, j in rows.values()}
    return FusionSummary(n_journey_signs=len(signs), created=created, updated=updated,
                         removed=removed, unchanged=unchanged,
                         biased_journeys=sorted(id_of_key.get(k, k) for k in fused.biased_journeys))


def _log(what: str, summary: FusionSummary) -> None:
    log.info("map fusion after %s: %d journey signs -> %d created, %d updated, %d removed, "
             "%d unchanged map signs; biased journeys: %s", what, summary.n_journey_signs,
             len(summary.created), len(summary.updated), len(summary.removed), summary.unchanged,
             ", ".join(summary.biased_journeys) or "none")


class JourneyRunning(Exception):
    """The journey is being processed; it cannot be deleted now."""


def delete_journey_and_bundle(settings: Settings, store: storage.BundleStore, journey_id: str) -> bool:
    """Delete a journey with its signs and coverage, re-fuse the map around it and release its
    bundle (kept while another journey has the same bytes). False when there is no such journey;
    ``JourneyRunning`` when it is being processed."""
    url = settings.effective_database_url
    with session_scope(url) as session:
        row = session.get(JourneyRow, journey_id)
        running = row is not None and row.status == "running"
        sha256 = row.bundle_sha256 if row is not None else None
    if running:
        raise JourneyRunning(journey_id)
    if not delete_journey(url, journey_id, settings):
        return False
    storage.release_bundle(url, store, sha256)
    return True

"""SQLAlchemy 2 models of the service. The schema itself is created only by the Alembic migrations in
``migrations/`` (SQLite and PostgreSQL alike); the bbox indexes differ per database and live there."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

from sqlalchemy import (JSON, CheckConstraint, DateTime, Float, ForeignKey, Index, Integer,
                        LargeBinary, String, Text, TypeDecorator, UniqueConstraint, and_, or_, text)
from sqlalchemy.orm import DeclarativeBase, Mapped, deferred, mapped_column

from app.pipeline.bundle.detections import MAX_CLASS_CHARS

ROLES = ("fleet", "reader", "admin")
STATUSES = ("queued", "running", "done", "failed")
# The stage of a queued journey that waits for its camera's calibration: it has no turn to
# calibrate on and its camera none yet (``jobs.cameras``). Claimed only once woken.
WAITING_FOR_CAMERA = "waiting_for_camera"
CALIBRATION_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")
# The stage of a done journey queued again to be re-processed with its camera's newer calibration.
REPROCESSING = "reprocessing"


def utc_now() -> datetime:
    return datetime.now(timezone.utc)


class UTCDateTime(TypeDecorator):
    """Aware UTC datetimes on every database: SQLite drops the zone on storage, so it is put back."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect) -> datetime | None:
        if value is not None and dialect.name == "sqlite":
            return value.astimezone(timezone.utc).replace(tzinfo=None)
        return value

    def process_result_value(self, value: datetime | None, dialect) -> datetime | None:
        if value is not None and value.tzinfo is None:
            return value.replace(tzinfo=timezone.utc)
        return value


class Base(DeclarativeBase):
    type_annotation_map = {datetime: UTCDateTime, dict[str, Any]: JSON, list[Any]: JSON}


class ApiKeyRow(Base):
    __tablename__ = "api_keys"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    role: Mapped[str] = mapped_column(String(16))
    key_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    # Set when revoked: the key is refused from then on, and the row stays for the journeys it owns.
    revoked_at: Mapped[datetime | None]
    # Last authentication, to within ``auth.LAST_USED_EVERY_S``: a read does not write every time.
    last_used_at: Mapped[datetime | None]


class AdminSessionRow(Base):
    """A dashboard sign-in: the SHA-256 of the opaque token in its cookie (never a key), whose key
    signed in (NULL: the environment's admin key; deleting the key ends its sessions) and when it
    stops working."""

    __tablename__ = "admin_sessions"

    token_sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    key_id: Mapped[int | None] = mapped_column(ForeignKey("api_keys.id", ondelete="CASCADE"),
                                               index=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    expires_at: Mapped[datetime] = mapped_column(index=True)


class JourneyRow(Base):
    __tablename__ = "journeys"
    # The same bytes from the same owner are one journey (see docs/service.md, "Re-uploads").
    __table_args__ = (UniqueConstraint("owner_key_id", "bundle_sha256", name="uq_journeys_owner_bundle"),)

    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    # NULL when uploaded with the environment's admin key, which has no row.
    owner_key_id: Mapped[int | None] = mapped_column(ForeignKey("api_keys.id"), index=True)
    camera_id: Mapped[str] = mapped_column(String(200), index=True)
    vehicle_id: Mapped[str | None] = mapped_column(String(200))
    captured_at: Mapped[str | None] = mapped_column(String(64))
    bundle_sha256: Mapped[str] = mapped_column(String(64))
    bundle_bytes: Mapped[int] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16), index=True, default="queued")
    stage: Mapped[str | None] = mapped_column(String(64))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    error: Mapped[str | None] = mapped_column(Text)
    n_frames: Mapped[int] = mapped_column(Integer)
    n_signs: Mapped[int | None] = mapped_column(Integer)
    calibration: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    calibration_source: Mapped[str | None] = mapped_column(String(16))
    timings_s: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    heartbeat_at: Mapped[datetime | None]
    # Incremented by every claim; a run only writes while the row still carries its own attempt.
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    # Set when this journey's self-calibration disagrees with the camera's stored one (jobs.fusion).
    calibration_flag: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    # What each pipeline stage did (StageReport.to_json() each), done or failed; NULL before 0006.
    report: Mapped[list[Any] | None] = mapped_column(JSON)
    # While queued with stage WAITING_FOR_CAMERA: what the journey waits for (0008).
    message: Mapped[str | None] = mapped_column(Text)
    # Its frames' size, once a run has read them (done or waiting; 0008).
    image_width: Mapped[int | None] = mapped_column(Integer)
    image_height: Mapped[int | None] = mapped_column(Integer)
    # While queued or running again with a registered calibration that superseded the one it was
    # given: that calibration's epoch (``jobs.cameras.reprocess_superseded``; 0009). Its earlier
    # signs are served meanwhile (``serves_result``).
    reprocess_epoch: Mapped[int | None] = mapped_column(Integer)
    # Its own estimate of an undeclared GPS antenna offset (``AntennaEstimate.to_json``), which
    # the vehicle's later journeys combine (``jobs.run``; 0013).
    antenna_estimate: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class JourneySignRow(Base):
    """One triangulated sign of one journey; ``observations`` is a JSON list of
    ``{"frame", "x", "y", "z", "box": [x1, y1, x2, y2] | null}`` (camera metres, original pixels)."""

    __tablename__ = "journey_signs"

    # "<journey id>:<track id>": a re-run of the journey reproduces the same keys.
    id: Mapped[str] = mapped_column(String, primary_key=True)
    journey_id: Mapped[str] = mapped_column(ForeignKey("journeys.id", ondelete="CASCADE"), index=True)
    track_id: Mapped[str] = mapped_column(String)
    cls: Mapped[str] = mapped_column("class", String(MAX_CLASS_CHARS), index=True)
    lat_deg: Mapped[float] = mapped_column(Float)
    lon_deg: Mapped[float] = mapped_column(Float)
    alt_m: Mapped[float | None] = mapped_column(Float)
    x_enu_m: Mapped[float] = mapped_column(Float)
    y_enu_m: Mapped[float] = mapped_column(Float)
    z_enu_m: Mapped[float] = mapped_column(Float)
    std_m: Mapped[float] = mapped_column(Float)
    r95_h_m: Mapped[float | None] = mapped_column(Float)  # horizontal radius, 95 % probability
    facing_deg: Mapped[float | None] = mapped_column(Float)  # compass bearing of the sign's face
    reprojection_rms_px: Mapped[float] = mapped_column(Float)
    observations: Mapped[list[Any]] = mapped_column(JSON)


class CameraColumns:
    """A camera's image size, intrinsics (OpenCV pixels) and their 1-sigma (own units; NULL:
    unknown), as the tables of calibrations share them."""

    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    fx: Mapped[float] = mapped_column(Float)
    fy: Mapped[float] = mapped_column(Float)
    cx: Mapped[float] = mapped_column(Float)
    cy: Mapped[float] = mapped_column(Float)
    k1: Mapped[float] = mapped_column(Float)
    k2: Mapped[float] = mapped_column(Float)
    sigma_fx: Mapped[float | None] = mapped_column(Float)
    sigma_fy: Mapped[float | None] = mapped_column(Float)
    sigma_cx: Mapped[float | None] = mapped_column(Float)
    sigma_cy: Mapped[float | None] = mapped_column(Float)
    sigma_k1: Mapped[float | None] = mapped_column(Float)
    sigma_k2: Mapped[float | None] = mapped_column(Float)

    def params(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in CALIBRATION_PARAMS}

    def sigma(self) -> dict[str, float | None]:
        return {k: getattr(self, f"sigma_{k}") for k in CALIBRATION_PARAMS}


class CalibrationRow(CameraColumns, Base):
    """A calibration of a camera: a journey's successful self-calibration (``source`` 'self',
    ``journey_id`` set) or one an admin registered ('registered', no journey). A registered one
    starts a new ``epoch`` of the camera, and so does a lens change (``epoch_reason``); a
    self-calibration otherwise joins the newest. The camera's later
    journeys get its newest epoch's registered calibration as given, or else what most of that
    epoch's self-calibrations agree on (``jobs.state.stored_calibration``;
    docs/decisions/registered-calibration.md)."""

    __tablename__ = "calibrations"
    __table_args__ = (
        CheckConstraint("(source = 'self' AND journey_id IS NOT NULL) "
                        "OR (source = 'registered' AND journey_id IS NULL)",
                        name="ck_calibrations_source"),
        Index("ix_calibrations_camera_epoch", "camera_id", "epoch"),
        Index("uq_calibrations_registered_epoch", "camera_id", "epoch", unique=True,
              sqlite_where=text("source = 'registered'"),
              postgresql_where=text("source = 'registered'")),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    camera_id: Mapped[str] = mapped_column(String(200), index=True)
    journey_id: Mapped[str | None] = mapped_column(ForeignKey("journeys.id", ondelete="CASCADE"),
                                                   index=True)
    source: Mapped[str] = mapped_column(String(16), default="self", server_default="self")
    epoch: Mapped[int] = mapped_column(Integer, default=1, server_default="1")
    # Self-calibrations only.
    n_images: Mapped[int | None] = mapped_column(Integer)
    n_registered: Mapped[int | None] = mapped_column(Integer)
    reprojection_error_px: Mapped[float | None] = mapped_column(Float)
    rotation_deg: Mapped[float | None] = mapped_column(Float)
    # Registered calibrations only: the key's name that registered it.
    registered_by: Mapped[str | None] = mapped_column(String(200))
    # The first self-calibration of an epoch a lens change started: why (migration 0010).
    epoch_reason: Mapped[str | None] = mapped_column(String(500))
    # A self-calibration's accepted turn window (``types.WindowObservations`` as ``np.savez``
    # bytes, ``jobs.camera_fit``), for the camera's joint calibration; loaded only when asked
    # for (a few hundred kB). NULL: not kept (registered, or stored before migration 0011).
    window: Mapped[bytes | None] = deferred(mapped_column(LargeBinary))
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class CameraFitRow(CameraColumns, Base):
    """A camera's joint calibration over the turn windows of an epoch's self-calibrations
    (``jobs.camera_fit``; ``cameras.calibrate_jointly``). The newest of an epoch is what its later
    journeys are given, unless the epoch has a registered calibration. ``inputs``: the ids of
    the calibrations it considered, sorted (the same inputs are not fitted twice); ``used``
    those in the fit; ``left_out`` id -> why not; ``rms_px`` id -> its window's reprojection
    error under the result."""

    __tablename__ = "camera_fits"
    __table_args__ = (Index("ix_camera_fits_camera_epoch", "camera_id", "epoch"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    camera_id: Mapped[str] = mapped_column(String(200))
    epoch: Mapped[int] = mapped_column(Integer)
    fy_resolved: Mapped[bool] = mapped_column(default=False)
    inputs: Mapped[list] = mapped_column(JSON)
    used: Mapped[list] = mapped_column(JSON)
    left_out: Mapped[dict] = mapped_column(JSON)
    rms_px: Mapped[dict] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)


class VehicleRow(Base):
    """What an admin said of a vehicle (``PUT /api/v1/vehicles/{vehicle_id}``): where its GPS
    antenna sits relative to its camera (``{"forward", "left", "up"}``, metres, the contract's
    section 1b), applied to its journeys whose manifest gives none (``jobs.run``)."""

    __tablename__ = "vehicles"

    vehicle_id: Mapped[str] = mapped_column(String(200), primary_key=True)
    gps_antenna_offset_m: Mapped[dict | None] = mapped_column(JSON)
    updated_by: Mapped[str | None] = mapped_column(String(200))
    updated_at: Mapped[datetime] = mapped_column(default=utc_now)


class MapSignRow(Base):
    """One fused sign of the map (``app.fusion.MapSign``); ``removed_at`` set = a tombstone kept
    for GET /signs/changes. ``cov_enu`` is the (3, 3) ENU covariance as nested lists, m^2."""

    __tablename__ = "map_signs"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    cls: Mapped[str] = mapped_column("class", String(MAX_CLASS_CHARS), index=True)
    lat_deg: Mapped[float] = mapped_column(Float)
    lon_deg: Mapped[float] = mapped_column(Float)
    alt_m: Mapped[float | None] = mapped_column(Float)
    cov_enu: Mapped[list[Any]] = mapped_column(JSON)
    std_m: Mapped[float] = mapped_column(Float)
    facing_deg: Mapped[float | None] = mapped_column(Float)  # compass bearing of the sign's face
    n_journeys: Mapped[int] = mapped_column(Integer)
    n_observations: Mapped[int] = mapped_column(Integer)
    first_seen_at: Mapped[datetime]
    last_seen_at: Mapped[datetime]
    state: Mapped[str] = mapped_column(String(32))
    evidence: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utc_now)
    updated_at: Mapped[datetime] = mapped_column(default=utc_now, index=True)
    removed_at: Mapped[datetime | None]


class MapSignMemberRow(Base):
    __tablename__ = "map_sign_members"

    map_sign_id: Mapped[str] = mapped_column(ForeignKey("map_signs.id", ondelete="CASCADE"),
                                             primary_key=True)
    journey_sign_id: Mapped[str] = mapped_column(
        ForeignKey("journey_signs.id", ondelete="CASCADE"), primary_key=True, index=True)
    weight: Mapped[float] = mapped_column(Float)


class CoverageRow(Base):
    """Where a done journey's camera looked: aligned poses ``poses`` (N x 12 floats, the rows of
    T_world_cam[:3, :4], ENU metres at the origin), the camera model, and the bbox of its centres."""

    __tablename__ = "journey_coverage"

    journey_id: Mapped[str] = mapped_column(ForeignKey("journeys.id", ondelete="CASCADE"),
                                            primary_key=True)
    journey_key: Mapped[str] = mapped_column(String(120))
    captured_at_s: Mapped[float] = mapped_column(Float)
    origin_lat_deg: Mapped[float] = mapped_column(Float)
    origin_lon_deg: Mapped[float] = mapped_column(Float)
    origin_alt_m: Mapped[float] = mapped_column(Float)
    camera: Mapped[dict[str, Any]] = mapped_column(JSON)
    frame_ids: Mapped[list[Any]] = mapped_column(JSON)
    poses: Mapped[list[Any]] = mapped_column(JSON)
    min_lat_deg: Mapped[float | None] = mapped_column(Float)
    min_lon_deg: Mapped[float | None] = mapped_column(Float)
    max_lat_deg: Mapped[float | None] = mapped_column(Float)
    max_lon_deg: Mapped[float | None] = mapped_column(Float)


def serves_result():
    """A journey whose signs count (in the map's fusion and its reads): done, or done before and
    being re-processed now (``JourneyRow.reprocess_epoch``) until the new run replaces them."""
    return or_(JourneyRow.status == "done",
               and_(JourneyRow.reprocess_epoch.is_not(None),
                    JourneyRow.status.in_(("queued", "running"))))

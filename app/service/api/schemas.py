"""Response models of the HTTP API (the wire contract, section 2), with examples for /docs."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from app.pipeline.bundle.manifest import AntennaOffsetIn

JOURNEY_ID_EXAMPLE = "6f1c2a3e-8d4b-4f7e-9a51-0c2d3e4f5a6b"
# Ids and text filters in paths and queries: PostgreSQL text cannot hold NUL, so one with NUL is
# refused as invalid input (422) instead of failing in the database (a 500, found by fuzzing).
NO_NUL = r"^[^\x00]*$"
# How much of a requested id an error detail echoes: a real id is far shorter (a journey's is 36
# characters, a map sign's at most 64), and a 60 KB one was sent back whole (issue 70).
MAX_ECHOED_ID_CHARS = 64


def echoed_id(value: str) -> str:
    """``value`` as an error detail may echo it: cut to ``MAX_ECHOED_ID_CHARS`` with an ellipsis."""
    if len(value) <= MAX_ECHOED_ID_CHARS:
        return value
    return value[:MAX_ECHOED_ID_CHARS - 1] + "\u2026"


class ErrorOut(BaseModel):
    detail: Any = Field(description="what is wrong, for a human", examples=[
        "gps.csv: timestamp_s must increase (row 12)"])


# The error answers every route with a key can give (``responses=`` of the route decorators).
AUTH_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorOut, "description": "no, unknown or revoked API key"},
    403: {"model": ErrorOut, "description": "the key's role may not make this call"},
    429: {"model": ErrorOut, "description": "too many unknown keys from this client address; "
                                            "any key is refused until Retry-After seconds pass",
          "headers": {"Retry-After": {"description": "seconds to wait",
                                      "schema": {"type": "integer"}}}},
}


class JourneyAccepted(BaseModel):
    id: str = Field(examples=[JOURNEY_ID_EXAMPLE])
    status: Literal["queued", "running", "done", "failed"] = Field(
        description="'queued' for a new upload; a re-upload of the same bytes answers the existing "
                    "journey's current status")


class CalibrationOut(BaseModel):
    """Pinhole + two-coefficient radial model, pixels of the original image (OpenCV convention)."""

    fx: float = Field(examples=[721.5])
    fy: float = Field(examples=[721.5])
    cx: float = Field(examples=[609.6])
    cy: float = Field(examples=[172.9])
    k1: float = Field(examples=[-0.3])
    k2: float = Field(examples=[0.1])


class StageReportOut(BaseModel):
    stage: str = Field(examples=["calibrate"])
    summary: str = Field(description="how the stage ended, one line",
                         examples=["self-calibrated on turn 1: 48 of 52 images registered"])
    details: list[str] = Field(description="one line per thing it tried")


class JourneyOut(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{
        "id": JOURNEY_ID_EXAMPLE, "status": "done", "stage": "done", "progress": 1.0, "error": None,
        "calibration": {"fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9, "k1": -0.3, "k2": 0.1},
        "calibration_source": "self", "n_frames": 120, "n_signs": 4, "camera_id": "cam-17",
        "vehicle_id": "van-3", "captured_at": "2026-11-20T08:15:00Z", "attempts": 1,
        "timings_s": {"turns": 0.02, "calibrate": 31.2, "ego_motion": 24.8, "total_s": 61.0},
        "created_at": "2026-11-21T10:00:00Z", "started_at": "2026-11-21T10:00:01Z",
        "finished_at": "2026-11-21T10:01:02Z"}]})

    id: str
    status: Literal["queued", "running", "done", "failed"]
    stage: str | None = Field(description="pipeline stage running now, or where it failed; "
                                          "'waiting_for_camera' for a queued journey that "
                                          "waits for its camera's calibration, "
                                          "'reprocessing' for a done one queued again "
                                          "(see `message`)")
    progress: float = Field(ge=0.0, le=1.0)
    error: str | None = Field(description="why the journey failed")
    message: str | None = Field(
        None, description="while queued with stage 'waiting_for_camera': what it waits for. It "
                          "has no turn to calibrate on and its camera no calibration yet; it "
                          "resumes by itself once the camera has one (a journey of the camera "
                          "with a turn, or one registered: PUT /cameras/{camera_id}/calibration)."
                          " While queued or running again with a registered calibration that "
                          "superseded the one it was given: 'reprocessing: camera ID calibration "
                          "epoch N' (its earlier signs are served until the new run replaces "
                          "them). After a re-processing that failed: why (its earlier result is "
                          "kept)")
    calibration: CalibrationOut | None = Field(description="the camera model used, once done")
    calibration_source: str | None = Field(
        description="'self' (this journey calibrated the camera), 'checked' (its turn confirmed "
                    "the camera's stored calibration, which it used), 'supplied' (an earlier "
                    "calibration of the same camera_id), 'prior' (the manifest's hint)")
    n_frames: int
    n_signs: int | None
    camera_id: str
    vehicle_id: str | None
    captured_at: str | None
    attempts: int = Field(description="runs started; more than 1 after a worker was lost")
    timings_s: dict[str, float | None] | None = Field(description="seconds per pipeline stage")
    calibration_flag: dict[str, Any] | None = Field(
        None, description="set when this journey's self-calibration disagrees with the camera's "
                          "stored one (fx/fy or cx/cy off by more than 3 %): reason and deviations")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    report: list[StageReportOut] | None = Field(
        None, description="what each pipeline stage did, in order (a failed journey's last entry "
                          "is the stage that failed); null for journeys processed before reports "
                          "existed")


class PointGeometry(BaseModel):
    type: Literal["Point"] = "Point"
    coordinates: list[float] = Field(description="[lon, lat, alt_m]; alt_m only when uploaded",
                                     examples=[[8.4183456, 49.0110123, 114.1]])


class ObservationOut(BaseModel):
    frame: str = Field(examples=["000088"])
    x: float = Field(description="metres right of the camera", examples=[3.1])
    y: float = Field(description="metres below the camera", examples=[-1.2])
    z: float = Field(description="metres in front of the camera", examples=[17.4])
    box: list[float] | None = Field(None, description="the detection [x1, y1, x2, y2], pixels")


class SignProperties(BaseModel):
    model_config = ConfigDict(extra="allow", populate_by_name=True)

    id: str = Field(examples=[f"{JOURNEY_ID_EXAMPLE}:0"])
    class_: str = Field(alias="class", examples=["stop"])
    track_id: str | None = Field(None, examples=["0"])
    journey_id: str | None = Field(None, examples=[JOURNEY_ID_EXAMPLE])
    std_m: float | None = Field(None, description="1-sigma position uncertainty (triangulation, "
                                                  "poses, alignment and GPS), metres")
    r95_h_m: float | None = Field(None, description="horizontal radius holding the true position "
                                                    "with 95 % probability, metres")
    facing_deg: float | None = Field(None, description="compass bearing its face points to "
                                                       "(degrees clockwise from north)")
    reprojection_rms_px: float | None = None
    observations: list[ObservationOut] | None = Field(
        None, description="the sign in each observing frame's rectified camera, metres")


class PointFeature(BaseModel):
    """A GeoJSON Point feature; each kind of sign adds its ``properties``."""

    type: Literal["Feature"] = "Feature"
    id: str
    geometry: PointGeometry


class FeatureCollection(BaseModel):
    type: Literal["FeatureCollection"] = "FeatureCollection"


class SignFeature(PointFeature):
    properties: SignProperties


class SignCollection(FeatureCollection):
    features: list[SignFeature]


MapSignState = Literal["new", "confirmed", "possibly_removed"]


class MapSignProperties(BaseModel):
    model_config = ConfigDict(extra="allow", populate_by_name=True)

    id: str = Field(examples=["ms-3f2a9c0d1e4b5a69"])
    class_: str = Field(alias="class", examples=["stop"])
    state: MapSignState
    std_m: float = Field(description="horizontal 1-sigma of the fused position, metres")
    n_journeys: int
    n_observations: int
    first_seen_at: datetime
    last_seen_at: datetime
    facing_deg: float | None = Field(
        None, description="compass bearing its face points to (degrees clockwise from north), "
                          "the circular mean of the journeys'; null when unknown")


class MapSignFeature(PointFeature):
    properties: MapSignProperties


class MapSignCollection(FeatureCollection):
    features: list[MapSignFeature]
    next: str | None = Field(description="pass as `cursor` for the next page; null on the last")


class MapChanges(BaseModel):
    since: datetime
    until: datetime = Field(description="pass as the next call's `since`")
    created: list[MapSignFeature]
    updated: list[MapSignFeature]
    removed: list[dict[str, Any]] = Field(description="tombstones: {id, removed_at}")


class CalibrationSigmaOut(BaseModel):
    """1-sigma of each parameter in its own units; null: not known."""

    fx: float | None
    fy: float | None
    cx: float | None
    cy: float | None
    k1: float | None
    k2: float | None


class LeftOutOut(BaseModel):
    journey_id: str | None = Field(description="null for another owner's journey")
    reason: str = Field(examples=["fx 4.1 % off the registered calibration, over the 3 % the "
                                  "journeys must agree within"])


class CameraEpochOut(BaseModel):
    epoch: int = Field(description="1, 2, ...; a registered calibration or a lens change starts "
                                   "a new one")
    source: Literal["self", "registered"] = Field(
        description="'registered': an admin gave the epoch's calibration; 'self': its journeys "
                    "calibrated the camera")
    started_at: datetime
    calibration: CalibrationOut | None
    calibration_source: Literal["registered", "joint", "consensus"] | None = Field(
        None, description="where the epoch's calibration comes from (as the camera's `source`)")
    sigma: CalibrationSigmaOut | None
    journeys: int = Field(description="the journeys in the epoch's calibration")
    self_calibrations: int = Field(description="the epoch's self-calibrations, all")
    registered_by: str | None = Field(None, description="admin callers only: the key's name")
    reason: str | None = Field(
        None, description="why the epoch started: 'calibration registered', the camera's first "
                          "calibration, or a lens change (frames of another size, or journeys "
                          "that agree with each other and differ from the older epoch)")
    first_journey_id: str | None = Field(
        None, description="its first journey (a lens change's; null for a registered epoch "
                          "before any journey, or a journey of another fleet)")


class CameraOut(BaseModel):
    model_config = ConfigDict(json_schema_extra={"examples": [{
        "camera_id": "cam-17", "width": 1242, "height": 375,
        "calibration": {"fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9, "k1": -0.3,
                        "k2": 0.1},
        "source": "consensus", "epoch": 1,
        "sigma": {"fx": 1.2, "fy": 1.4, "cx": 0.8, "cy": 0.6, "k1": 0.002, "k2": 0.004},
        "sigma_basis": "standard error of the mean of 3 self-calibrations (their standard "
                       "deviation over sqrt(3))",
        "journeys": 3, "left_out": [], "waiting": 0, "reprocessing": 0,
        "epochs": [{"epoch": 1, "source": "self", "started_at": "2026-11-21T10:01:02Z",
                    "calibration": {"fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9,
                                    "k1": -0.3, "k2": 0.1},
                    "sigma": {"fx": 1.2, "fy": 1.4, "cx": 0.8, "cy": 0.6, "k1": 0.002,
                              "k2": 0.004},
                    "journeys": 3, "self_calibrations": 3, "registered_by": None}]}]})

    camera_id: str
    width: int | None = Field(description="image width of the calibration (or, without one, of "
                                          "the camera's journeys), pixels")
    height: int | None
    calibration: CalibrationOut | None = Field(
        description="what the camera's journeys without a turn are given; null: none yet")
    source: Literal["registered", "joint", "consensus"] | None = Field(
        description="'registered': as an admin gave it; 'joint': one bundle adjustment over the "
                    "turn windows of its epoch's newest self-calibrations, sharing the camera; "
                    "'consensus': the mean of the agreeing newest self-calibrations of its epoch "
                    "(before two of them kept their turn windows)")
    fy_resolved: bool | None = Field(
        None, description="joint calibrations: whether its journeys' turns pin fy (2 sigma "
                          "within 0.3 %); turns about one vertical axis leave the pixel aspect "
                          "weakly determined, and its sigma then says how far off fy may be")
    epoch: int | None = Field(description="the epoch the calibration is of (the newest)")
    sigma: CalibrationSigmaOut | None = Field(
        description="1-sigma of the calibration, same units: as registered (0 where none was "
                    "given), the joint fit's (the larger of its covariance's and the windows' "
                    "own spread over sqrt(n)), or the standard error of the consensus mean "
                    "(null for a single self-calibration: not known)")
    sigma_basis: str | None = Field(description="where the sigma comes from, in words")
    journeys: int = Field(description="the journeys in the calibration: those the joint fit "
                                      "used, the consensus's members, or the self-calibrations "
                                      "agreeing with a registered one")
    left_out: list[LeftOutOut] = Field(
        description="the epoch's journeys whose self-calibration disagreed, and why")
    waiting: int = Field(description="journeys queued with stage waiting_for_camera: no turn, "
                                     "and no calibration of this camera yet")
    reprocessing: int = Field(0, description="journeys queued or running again (stage "
                                             "`reprocessing`, then the pipeline's) with the "
                                             "registered calibration that superseded the one "
                                             "they were given; they serve their earlier signs "
                                             "until the new run replaces them")
    epochs: list[CameraEpochOut] = Field(description="oldest first; the last is the current")


class CameraRegistered(CameraOut):
    registered_epoch: int = Field(description="the epoch of the registered calibration")
    new_epoch: bool = Field(description="false when it was registered already (same values): "
                                        "nothing changed")
    resumed: list[str] = Field(description="journeys that were waiting for this camera and are "
                                           "queued again")
    reprocess_queued: list[str] = Field(
        [], description="done journeys that were given a calibration of this camera other than "
                        "the registered one (not self-calibrated, frames of its size), queued "
                        "now to be processed again with it; empty when nothing is left to "
                        "re-process (the same registration again)")


class AntennaOffsetOut(BaseModel):
    forward: float
    left: float
    up: float


class VehicleIn(BaseModel):
    model_config = ConfigDict(extra="forbid")

    gps_antenna_offset_m: AntennaOffsetIn | None = Field(
        description="the GPS antenna's position minus the camera's, metres, in the vehicle's axes "
                    "(forward along travel, left, up), each within ±10 m: applied to the "
                    "vehicle's journeys whose manifest gives none (a manifest's wins); null "
                    "forgets it")


class AntennaEstimateOut(BaseModel):
    forward_m: float
    left_m: float
    sigma_forward_m: float
    sigma_left_m: float
    n_journeys: int = Field(description="the vehicle's done journeys whose turns told it")


class VehicleOut(BaseModel):
    vehicle_id: str
    gps_antenna_offset_m: AntennaOffsetOut | None
    gps_antenna_offset_estimated: AntennaEstimateOut | None = Field(
        None, description="where nothing is set: the horizontal offset the vehicle's journeys "
                          "estimated from their turns, combined (the worker applies it once its "
                          "sigma is under 0.2 m)")
    updated_by: str | None = Field(None, description="the admin key's name that set it")
    updated_at: datetime | None = Field(None, description="when it was set (null: never)")

"""``manifest.json`` of a journey bundle (contract section 1). Unknown keys are ignored; values are
checked strictly (a number must be a JSON number, not a string), so a mistake is reported rather
than guessed around.

Optional fields besides the contract's section 1: ``gps_time_offset_s`` (section 1a: seconds to
add to the camera's time to get GPS time), ``gps_antenna_offset_m`` (section 1b: the GPS antenna's
position minus the camera's, metres, in vehicle axes) and ``frame_rate_hz`` (this project's
extension: frame i was taken at ``captured_at`` + i / ``frame_rate_hz``; it lets frames be placed
on a ``gps.gpx`` track that has not one point per frame)."""

from __future__ import annotations

import json

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from app.pipeline.bundle.csv_table import CONTROL_CHARS, MAX_TEXT_CHARS, decode_text
from app.pipeline.bundle.gps import parse_iso_time
from app.pipeline.types import AntennaOffset, BundleError, CameraModel

FORMAT = "signmap-journey/1"
MAX_FRAME_RATE_HZ = 1000.0  # beyond any camera's frame rate; a larger value is a unit mistake
MAX_GPS_TIME_OFFSET_S = 1e6  # 11 days: more is no clock error but a wrong date
# Bounds of a camera prior that any real camera keeps (pixels; radial coefficients): a hint beyond
# them is no camera, and a value such as 1e308 would turn the self-calibration into NaN.
MAX_PRIOR_PX = 1e6
MAX_PRIOR_K = 100.0
# An antenna further than this from the camera along any axis is on no vehicle that carries both: a
# larger value is a unit mistake (centimetres or millimetres).
MAX_ANTENNA_OFFSET_M = 10.0


class CameraPrior(BaseModel):
    model_config = ConfigDict(extra="ignore", strict=True, allow_inf_nan=False)

    fx: float = Field(gt=0, le=MAX_PRIOR_PX)
    fy: float = Field(gt=0, le=MAX_PRIOR_PX)
    cx: float = Field(ge=-MAX_PRIOR_PX, le=MAX_PRIOR_PX)
    cy: float = Field(ge=-MAX_PRIOR_PX, le=MAX_PRIOR_PX)
    k1: float = Field(0.0, ge=-MAX_PRIOR_K, le=MAX_PRIOR_K)
    k2: float = Field(0.0, ge=-MAX_PRIOR_K, le=MAX_PRIOR_K)

    def camera(self, width: int, height: int) -> CameraModel:
        return CameraModel(width=width, height=height, fx=self.fx, fy=self.fy, cx=self.cx,
                           cy=self.cy, k1=self.k1, k2=self.k2)


class AntennaOffsetIn(BaseModel):
    """``gps_antenna_offset_m``: the antenna's position minus the camera's, metres, in the vehicle's
    axes; all three keys are required (a missing one is no zero)."""

    model_config = ConfigDict(extra="ignore", strict=True, allow_inf_nan=False)

    forward: float = Field(ge=-MAX_ANTENNA_OFFSET_M, le=MAX_ANTENNA_OFFSET_M)
    left: float = Field(ge=-MAX_ANTENNA_OFFSET_M, le=MAX_ANTENNA_OFFSET_M)
    up: float = Field(ge=-MAX_ANTENNA_OFFSET_M, le=MAX_ANTENNA_OFFSET_M)

    def offset(self) -> AntennaOffset:
        return AntennaOffset(forward_m=self.forward, left_m=self.left, up_m=self.up)


class Manifest(BaseModel):
    model_config = ConfigDict(extra="ignore", strict=True)

    format: str
    # The lengths of the service's columns; PostgreSQL refuses longer text and any NUL.
    camera_id: str = Field(max_length=MAX_TEXT_CHARS)
    vehicle_id: str | None = Field(None, max_length=MAX_TEXT_CHARS)
    captured_at: str | None = Field(None, max_length=64)
    camera_prior: CameraPrior | None = None
    frame_rate_hz: float | None = Field(None, gt=0, le=MAX_FRAME_RATE_HZ, allow_inf_nan=False)
    gps_time_offset_s: float | None = Field(None, ge=-MAX_GPS_TIME_OFFSET_S,
                                            le=MAX_GPS_TIME_OFFSET_S, allow_inf_nan=False)
    gps_antenna_offset_m: AntennaOffsetIn | None = None

    @field_validator("camera_id", "vehicle_id", "captured_at")
    @classmethod
    def _printable(cls, value: str | None) -> str | None:
        # NUL breaks PostgreSQL; a newline in a logged camera id forged a log line.
        bad = None if value is None else CONTROL_CHARS.search(value)
        if bad:
            raise ValueError(f"must not contain control characters ({bad.group()!r} at "
                             f"character {bad.start() + 1})")
        return value

    @field_validator("camera_id")
    @classmethod
    def _non_empty(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("must be a non-empty string")
        return value

    @field_validator("captured_at")
    @classmethod
    def _iso_time(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                parse_iso_time(value, "captured_at")
            except BundleError as exc:
                raise ValueError(exc.reason) from None
        return value


def _parse_int(digits: str) -> int | float:
    # Python refuses to convert integers of more than 4300 digits (a ValueError naming no field);
    # as a float such a number is infinite, which the field it stands in then refuses by name.
    return int(digits) if len(digits) <= 400 else float(digits)


def parse_manifest(data: bytes) -> Manifest:
    """``manifest.json`` bytes -> Manifest, or a BundleError saying what to fix."""
    text = decode_text(data, "manifest.json")
    try:
        obj = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise BundleError(f"manifest.json is not valid JSON: {exc}") from None
    except RecursionError:
        raise BundleError("manifest.json is not valid JSON: nested too deeply") from None
    if not isinstance(obj, dict):
        raise BundleError(f"manifest.json must be a JSON object, got {type(obj).__name__}")
    if "format" not in obj:
        raise BundleError(f'manifest.json has no "format"; expected "{FORMAT}"')
    if obj["format"] != FORMAT:
        raise BundleError(f"manifest.json format is {json.dumps(obj['format'])[:80]}, expected "
                          f'"{FORMAT}"')
    try:
        return Manifest.model_validate(obj)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in exc.errors()[:5])
        raise BundleError(f"manifest.json is invalid: {problems}") from None

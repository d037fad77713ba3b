"""Routes of vehicles (base path /api/v1, admin only): where a vehicle's GPS antenna sits
relative to its camera, for its journeys whose manifest does not say (issue 67, item 1; the
worker applies it, ``jobs.run``). A vehicle id is any printable string of the manifest, ``/``
included, as a camera id is (``routes.cameras``)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, status
from sqlalchemy.orm import Session
from starlette.convertors import PathConvertor, register_url_convertor

from app.service.api.schemas import AUTH_ERRORS, NO_NUL, ErrorOut, VehicleIn, VehicleOut, echoed_id
from app.service.db.models import VehicleRow, utc_now
from app.service.deps import Admin, SessionDep
from app.service.jobs import state

router = APIRouter(prefix="/api/v1")


class _VehicleIdConvertor(PathConvertor):
    regex = r"[\s\S]*"


register_url_convertor("vehicle_id", _VehicleIdConvertor())
VehicleId = Annotated[str, Path(pattern=NO_NUL, max_length=200,
                                description="the manifest's vehicle_id")]


def _out(session: Session, vehicle_id: str, row: VehicleRow | None) -> dict[str, Any]:
    estimate = state.vehicle_estimate(session, vehicle_id)
    return {"vehicle_id": vehicle_id,
            "gps_antenna_offset_m": row.gps_antenna_offset_m if row is not None else None,
            "gps_antenna_offset_estimated": estimate.to_json() if estimate is not None else None,
            "updated_by": row.updated_by if row is not None else None,
            "updated_at": row.updated_at if row is not None else None}


@router.get("/vehicles/{vehicle_id:vehicle_id}", response_model=VehicleOut,
            summary="A vehicle's GPS antenna offset (admin)",
            description="The offset set for the vehicle, and what its done journeys estimated "
                        "from their turns where none was given, combined.",
            responses={**AUTH_ERRORS, 404: {"model": ErrorOut,
                                            "description": "nothing was set for this vehicle "
                                                           "and none of its journeys estimated "
                                                           "an offset"}})
def get_vehicle(vehicle_id: VehicleId, who: Admin, session: SessionDep) -> dict[str, Any]:
    row = session.get(VehicleRow, vehicle_id)
    out = _out(session, vehicle_id, row)
    if row is None and out["gps_antenna_offset_estimated"] is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"nothing set for vehicle {echoed_id(vehicle_id)}, nor estimated")
    return out


@router.put("/vehicles/{vehicle_id:vehicle_id}", response_model=VehicleOut,
            summary="Set a vehicle's GPS antenna offset (admin)",
            description="Where the vehicle's GPS antenna sits relative to its camera, applied to "
                        "the vehicle's journeys processed from now on whose manifest gives no "
                        "`gps_antenna_offset_m` (a manifest's wins); the journey's `align` "
                        "report names the vehicle. Null forgets it. Journeys done before keep "
                        "their result (Retry runs one again).",
            responses={**AUTH_ERRORS,
                       400: {"model": ErrorOut, "description": "the body is not JSON"},
                       422: {"model": ErrorOut,
                                            "description": "a missing key, or a value that is "
                                                           "not a finite number within ±10 m"}})
def put_vehicle(vehicle_id: VehicleId, body: VehicleIn, who: Admin,
                session: SessionDep) -> dict[str, Any]:
    row = session.get(VehicleRow, vehicle_id) or VehicleRow(vehicle_id=vehicle_id)
    offset = body.gps_antenna_offset_m
    row.gps_antenna_offset_m = offset.model_dump() if offset is not None else None
    row.updated_by, row.updated_at = who.name, utc_now()
    session.add(row)
    session.flush()
    return _out(session, vehicle_id, row)

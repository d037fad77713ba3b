"""A vehicle's GPS antenna offset set by an admin (``PUT /api/v1/vehicles/{id}``, issue 67), on
SQLite and PostgreSQL: what the API answers and refuses, and what the worker hands the pipeline
(``jobs.run._with_vehicle_antenna``: the vehicle's offset when the manifest gives none; a
manifest's wins; with neither, what the vehicle's done journeys estimated from their turns,
combined). ``tests/e2e/test_antenna_offset.py`` runs one through a real Celery worker."""

from __future__ import annotations

import secrets

import numpy as np
import pytest

from app.pipeline.types import AntennaOffset, Journey
from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from app.service.jobs.run import _with_vehicle_antenna
from tests.utils.stack import ADMIN_KEY, auth

OFFSET = {"forward": -1.09, "left": 0.25, "up": -0.72}


def _journey(vehicle_id: str | None, offset: AntennaOffset | None = None) -> Journey:
    return Journey(camera_id="cam", frames=[], lat_deg=np.zeros(0), lon_deg=np.zeros(0),
                   alt_m=np.zeros(0), detections=[], image_width=64, image_height=48,
                   vehicle_id=vehicle_id, gps_antenna_offset=offset)


def test_an_admin_sets_reads_and_forgets_a_vehicles_offset(stack):
    vehicle = f"van/{secrets.token_hex(3)}"  # a '/' in an id, as the manifest allows
    admin = auth(ADMIN_KEY)
    with stack.client() as client:
        assert client.get(f"/api/v1/vehicles/{vehicle}", headers=admin).status_code == 404
        response = client.put(f"/api/v1/vehicles/{vehicle}", headers=admin,
                              json={"gps_antenna_offset_m": OFFSET})
        assert response.status_code == 200, response.text
        body = client.get(f"/api/v1/vehicles/{vehicle}", headers=admin).json()
        assert body["vehicle_id"] == vehicle and body["gps_antenna_offset_m"] == OFFSET
        assert body["updated_by"] == "SIGNMAP_ADMIN_KEY"

        journey = _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle))
        assert journey.gps_antenna_offset == AntennaOffset(-1.09, 0.25, -0.72,
                                                           source=f"vehicle {vehicle}")
        declared = AntennaOffset(0.5, 0.0, 1.0)
        assert _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle, declared)) \
            .gps_antenna_offset == declared  # the manifest's wins
        assert _with_vehicle_antenna(stack.url, "j-new", _journey("other")).gps_antenna_offset is None

        response = client.put(f"/api/v1/vehicles/{vehicle}", headers=admin,
                              json={"gps_antenna_offset_m": None})
        assert response.status_code == 200 and response.json()["gps_antenna_offset_m"] is None
        assert _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle)).gps_antenna_offset is None


def _done_journey(journey_id: str, vehicle_id: str, estimate: dict | None,
                  status: str = "done") -> JourneyRow:
    return JourneyRow(id=journey_id, camera_id="cam", vehicle_id=vehicle_id,
                      bundle_sha256=journey_id.ljust(64, "0"), bundle_bytes=1, n_frames=80,
                      status=status, antenna_estimate=estimate)


def test_a_vehicles_journeys_estimates_are_combined_for_its_next_journey(stack):
    vehicle = f"van-{secrets.token_hex(3)}"
    tag = secrets.token_hex(4)
    first = {"forward_m": -1.0, "left_m": 0.2, "sigma_forward_m": 0.3, "sigma_left_m": 0.4,
             "n_journeys": 1}
    second = {**first, "forward_m": -1.2, "sigma_forward_m": 0.3}
    with session_scope(stack.url) as session:
        session.add_all([_done_journey(f"{tag}-a", vehicle, first),
                         _done_journey(f"{tag}-b", vehicle, second),
                         _done_journey(f"{tag}-c", vehicle, None),  # declared, or no turn
                         _done_journey(f"{tag}-d", vehicle, {**first, "forward_m": 9.0},
                                       status="failed"),
                         _done_journey(f"{tag}-e", "another", first)])
    # Its next journey gets both done journeys' estimates combined (equal sigmas: the mean, the
    # sigma over sqrt(2)); a journey run again does not count its own earlier result.
    prior = _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle)).antenna_prior
    assert prior.n_journeys == 2
    assert np.allclose([prior.forward_m, prior.left_m, prior.sigma_forward_m, prior.sigma_left_m],
                       [-1.1, 0.2, 0.3 / np.sqrt(2), 0.4 / np.sqrt(2)])
    again = _with_vehicle_antenna(stack.url, f"{tag}-b", _journey(vehicle)).antenna_prior
    assert again.n_journeys == 1 and again.forward_m == -1.0
    assert _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle)).antenna_prior_source \
        == f"vehicle {vehicle}"
    with stack.client() as client:
        body = client.get(f"/api/v1/vehicles/{vehicle}", headers=auth(ADMIN_KEY)).json()
        assert body["gps_antenna_offset_m"] is None and body["updated_at"] is None
        assert body["gps_antenna_offset_estimated"]["n_journeys"] == 2
        assert np.isclose(body["gps_antenna_offset_estimated"]["forward_m"], -1.1)
        # An offset set by an admin wins: the pipeline gets it, not the estimates.
        client.put(f"/api/v1/vehicles/{vehicle}", headers=auth(ADMIN_KEY),
                   json={"gps_antenna_offset_m": OFFSET})
    journey = _with_vehicle_antenna(stack.url, "j-new", _journey(vehicle))
    assert journey.gps_antenna_offset.forward_m == -1.09 and journey.antenna_prior is None


@pytest.mark.parametrize("body, field", [
    ({"gps_antenna_offset_m": {"forward": 109, "left": 25, "up": -72}}, "forward"),
    ({"gps_antenna_offset_m": {"forward": -1.09, "left": 0.25}}, "up"),
    ({"gps_antenna_offset_m": {"forward": "1", "left": 0, "up": 0}}, "forward"),
    ({}, "gps_antenna_offset_m"),
])
def test_a_bad_offset_is_a_422_naming_the_field(sqlite, body, field):
    with sqlite.client() as client:
        response = client.put("/api/v1/vehicles/van-1", headers=auth(ADMIN_KEY), json=body)
        assert response.status_code == 422, response.text
        assert any(e["loc"][-1] == field for e in response.json()["detail"]), response.text
        assert client.get("/api/v1/vehicles/van-1", headers=auth(ADMIN_KEY)).status_code == 404


def test_only_an_admin_may(sqlite):
    with sqlite.client() as client:
        for role in ("fleet", "reader"):
            key = auth(sqlite.key(role))
            assert client.put("/api/v1/vehicles/van-1", headers=key,
                              json={"gps_antenna_offset_m": OFFSET}).status_code == 403
            assert client.get("/api/v1/vehicles/van-1", headers=key).status_code == 403


@pytest.fixture
def sqlite(tmp_path):
    from tests.utils.stack import sqlite_stack

    return sqlite_stack(tmp_path / "data")


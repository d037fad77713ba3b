"""A fleet key is refused the map (docs/decisions/fleet-key-map.md), and the refusal says what to
use instead: its own journeys' signs, or a reader key for the map."""

from __future__ import annotations

import pytest

from tests.utils.stack import auth, sqlite_stack

MAP_ROUTES = ["/api/v1/signs?bbox=0,0,1,1", "/api/v1/tiles/1/0/0.mvt", "/api/v1/signs/x",
              "/api/v1/signs/changes?since=2020-01-01T00:00:00Z"]


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    stack = sqlite_stack(tmp_path_factory.mktemp("fleet-map") / "data")
    with stack.client() as client:
        yield stack, client


@pytest.mark.parametrize("path", MAP_ROUTES)
def test_a_fleet_key_on_the_map_is_told_what_to_use_instead(service, path):
    stack, client = service
    answer = client.get(path, headers=auth(stack.key("fleet")))
    assert answer.status_code == 403
    assert answer.json()["detail"] == (
        "this call needs a reader or admin key, not fleet; a fleet key reads only its own "
        "journeys (a journey's signs: GET /api/v1/journeys/{id}/signs). To read the map, use a "
        "reader key: an operator makes one with `signmap keys create --role reader`")
    assert client.get(path, headers=auth(stack.key("reader"))).status_code != 403


def test_other_refusals_keep_their_short_detail(service):
    stack, client = service
    answer = client.get("/api/v1/journeys", headers=auth(stack.key("reader")))
    assert answer.json()["detail"] == "this call needs a fleet or admin key, not reader"

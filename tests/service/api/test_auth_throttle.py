"""Guessing keys is throttled per client address (TestClient, SQLite; the count is in the API
process): past SIGNMAP_AUTH_FAILURE_LIMIT unknown Bearer keys or refused dashboard sign-ins within
SIGNMAP_AUTH_FAILURE_WINDOW_S, the address gets 429 with Retry-After, the right key included,
until the window passes; other addresses are unaffected, and a success clears nothing. The count
itself forgets expired addresses and holds a bounded number."""

from __future__ import annotations

import time
from contextlib import contextmanager

from fastapi.testclient import TestClient

from app.commands.service import create_service_app
from app.service.admin.session import COOKIE
from app.service.auth import FailureThrottle
from tests.utils.stack import ADMIN_KEY, auth, sqlite_stack

ATTACKER, NEIGHBOUR = ("203.0.113.7", 40000), ("198.51.100.9", 40000)


@contextmanager
def _clients(tmp_path, **settings):
    """The attacker's and another address's clients of one running API."""
    stack = sqlite_stack(tmp_path / "data", **settings)
    app = create_service_app(stack.settings)
    with TestClient(app, client=ATTACKER) as attacker:
        yield stack, attacker, TestClient(app, client=NEIGHBOUR)


def _journeys(client, key: str):
    return client.get("/api/v1/journeys", headers=auth(key))


def _sign_in(client, key: str):
    return client.post("/admin/login", data={"key": key}, follow_redirects=False)


def _assert_throttled(answer) -> int:
    assert answer.status_code == 429, answer.text
    wait_s = int(answer.headers["retry-after"])
    assert 1 <= wait_s <= 60
    return wait_s


def test_wrong_admin_keys_at_the_sign_in_are_throttled(tmp_path):
    """The probe's case with the default settings: 10 wrong keys, then 429 even for the right one."""
    with _clients(tmp_path) as (stack, attacker, neighbour):
        for n in range(10):
            answer = _sign_in(attacker, f"guess-{n}")
            assert answer.status_code == 403 and "not an admin key" in answer.text
        answer = _sign_in(attacker, "guess-10")
        _assert_throttled(answer)
        assert "too many failed keys from this address" in answer.text
        answer = _sign_in(attacker, ADMIN_KEY)  # a guess that hits is refused as well
        _assert_throttled(answer)
        assert COOKIE not in answer.cookies
        # One count per address, for the dashboard and Bearer keys alike.
        assert _journeys(attacker, ADMIN_KEY).status_code == 429
        assert _sign_in(neighbour, ADMIN_KEY).status_code == 303
        assert _journeys(neighbour, stack.key("fleet")).status_code == 200


def test_unknown_bearer_keys_are_throttled_until_the_window_passes(tmp_path):
    with _clients(tmp_path, auth_failure_limit=3, auth_failure_window_s=2.0) as (
            stack, attacker, neighbour):
        fleet = stack.key("fleet")
        for n in range(3):
            answer = _journeys(attacker, f"guess-{n}")
            assert answer.status_code == 401 and answer.json()["detail"] == "unknown API key"
        counted = time.monotonic()  # every failure was counted before this
        answer = _journeys(attacker, "guess-3")
        wait_s = _assert_throttled(answer)
        assert wait_s <= 2
        assert answer.json()["detail"] == (f"too many failed keys from this address; "
                                           f"try again in {wait_s} s")
        assert _journeys(attacker, fleet).status_code == 429  # the right key too
        assert _journeys(attacker, "").status_code == 429
        # Another address: its own count, and its success clears nothing of the attacker's.
        assert _journeys(neighbour, "guess-x").status_code == 401
        assert _journeys(neighbour, fleet).status_code == 200
        assert _journeys(attacker, fleet).status_code == 429
        time.sleep(max(0.0, counted + 2.05 - time.monotonic()))  # every failure is 2 s old
        assert _journeys(attacker, fleet).status_code == 200
        assert _journeys(attacker, "guess-4").status_code == 401


def test_a_success_does_not_reset_the_count(tmp_path):
    with _clients(tmp_path, auth_failure_limit=3, auth_failure_window_s=30.0) as (
            stack, attacker, neighbour):
        fleet = stack.key("fleet")
        for n in range(2):
            assert _journeys(attacker, f"guess-{n}").status_code == 401
        assert _journeys(attacker, fleet).status_code == 200
        assert _journeys(attacker, "guess-2").status_code == 401
        _assert_throttled(_journeys(attacker, fleet))
        # Neither a missing key nor a valid key of the wrong role counts as a guess.
        for _ in range(5):
            assert neighbour.get("/api/v1/journeys").status_code == 401
            assert neighbour.get("/api/v1/signs", params={"bbox": "0,0,1,1"},
                                 headers=auth(fleet)).status_code == 403
        assert _journeys(neighbour, fleet).status_code == 200


def test_the_count_forgets_expired_addresses_and_keeps_a_bounded_number():
    now = [0.0]
    throttle = FailureThrottle(limit=2, window_s=10.0, max_addresses=3, clock=lambda: now[0])
    assert not throttle.failed("a") and throttle.failed("a")  # the 2nd reaches the limit
    assert throttle.retry_after_s("a") == 10
    now[0] = 9.5
    assert throttle.retry_after_s("a") == 1 and throttle.retry_after_s("b") == 0
    for address in "bcde":  # "a" failed least recently: dropped to keep 3
        throttle.failed(address)
    assert list(throttle._failures) == ["c", "d", "e"] and throttle.retry_after_s("a") == 0
    now[0] = 30.0
    throttle.failed("f")  # the others' failures are a window old: forgotten
    assert list(throttle._failures) == ["f"]

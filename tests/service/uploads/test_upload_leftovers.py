"""An upload that fails after its bundle was stored takes the bundle back (issue 70, item 3): with
the database refusing the journey's row, or the job queue refusing the journey, the answer is 503
and nothing remains under bundles/ or incoming/, unless another journey holds the same bytes."""

from __future__ import annotations

import pytest
from sqlalchemy import update
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.service import storage
from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from tests.utils import bundle_factory as bf
from tests.utils.stack import auth, sqlite_stack

DATA = bf.zip_bytes(bf.valid_files())


def _post(client, key: str, data: bytes = DATA):
    return client.post("/api/v1/journeys", headers=auth(key),
                       files={"bundle": ("journey.zip", data, "application/zip")})


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data")


@pytest.fixture
def row_commit_fails(monkeypatch):
    """The database refuses the commit that would store a journey row (as a read-only or full
    SQLite file does); every other commit goes through."""
    commit = Session.commit

    def refusing(session: Session) -> None:
        if any(isinstance(obj, JourneyRow) for obj in session.new):
            raise OperationalError("INSERT INTO journeys ...", {},
                                   Exception("attempt to write a readonly database"))
        commit(session)

    monkeypatch.setattr(Session, "commit", refusing)


def _journey_rows(stack) -> list[tuple[str, str]]:
    with session_scope(stack.url) as session:
        return [(r.status, r.bundle_sha256) for r in session.query(JourneyRow)]


def test_database_refusing_the_journey_row_leaves_no_bundle(stack, row_commit_fails):
    key = stack.key("fleet")
    with stack.client() as client:
        response = _post(client, key)
        assert response.status_code == 503, response.text
        assert response.json()["detail"] == "the database is unavailable; try again later"
        assert client.get("/api/v1/health").status_code == 200
    assert stack.stored_files() == []
    assert _journey_rows(stack) == []


def test_bundle_is_taken_back_even_when_the_database_cannot_be_read(stack, row_commit_fails,
                                                                    monkeypatch):
    def unreadable(*_args, **_kwargs):
        raise OperationalError("SELECT count(*) ...", {}, Exception("unable to open database"))

    monkeypatch.setattr(storage, "release_bundle", unreadable)
    key = stack.key("fleet")
    with stack.client() as client:
        assert _post(client, key).status_code == 503
    assert stack.stored_files() == []


def test_bytes_another_journey_holds_are_kept(stack, monkeypatch):
    first, second = stack.key("fleet"), stack.key("fleet")
    with stack.client() as client:
        assert _post(client, first).status_code == 202
        kept = stack.stored_files()
        assert len(kept) == 1
        commit = Session.commit

        def refusing(session: Session) -> None:
            if any(isinstance(obj, JourneyRow) for obj in session.new):
                raise OperationalError("INSERT", {}, Exception("disk I/O error"))
            commit(session)

        monkeypatch.setattr(Session, "commit", refusing)
        assert _post(client, second).status_code == 503
    assert stack.stored_files() == kept
    assert stack.count_journeys(first) == 1 and stack.count_journeys(second) == 0


def test_queue_refusing_the_journey_leaves_nothing(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        def unreachable(journey_id: str) -> None:
            raise ConnectionError("broker unreachable")

        client.app.state.queue.submit = unreachable
        response = _post(client, key)
    assert response.status_code == 503, response.text
    assert response.json()["detail"] == "the job queue is unreachable; try again later"
    assert stack.stored_files() == [] and _journey_rows(stack) == []


def test_failed_journey_that_cannot_be_queued_again_stays_failed(stack):
    """Left queued, no queue would hold it, and its next re-upload would answer 200 "queued"
    without queueing it."""
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = _post(client, key).json()["id"]
        with session_scope(stack.url) as session:
            session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                            .values(status="failed", error="earlier failure"))
        queue = client.app.state.queue
        submit = queue.submit

        def unreachable(journey_id: str) -> None:
            raise ConnectionError("broker unreachable")

        queue.submit = unreachable
        response = _post(client, key)
        assert response.status_code == 503, response.text
        with session_scope(stack.url) as session:
            row = session.get(JourneyRow, journey_id)
            assert (row.status, row.error) == (
                "failed", "could not be queued again: the job queue was unreachable; upload the "
                          "bundle again")
        queue.submit = submit
        again = _post(client, key)
    assert again.status_code == 202 and again.json() == {"id": journey_id, "status": "queued"}
    assert len(stack.stored_files()) == 1  # the journey's bundle, kept throughout

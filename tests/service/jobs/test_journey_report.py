"""The pipeline's per-stage report (issue 14): kept in the journey's row when it is done or fails,
given in the journey JSON of the API and shown on the dashboard's journey page. Through the real job
functions and the real pipeline on the real (SQLite) database."""

from __future__ import annotations

import html

import pytest
from sqlalchemy import update

from app.pipeline.types import StageReport
from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from app.service.jobs import run
from tests.utils.results.service_support import bf_zip, finish, made_result
from tests.utils.stack import ADMIN_KEY, auth, sqlite_stack, upload


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data")


def _row(stack, journey_id: str) -> JourneyRow:
    with session_scope(stack.url) as session:
        return session.get(JourneyRow, journey_id)


def _page(client, journey_id: str) -> str:
    assert client.post("/admin/login", data={"key": ADMIN_KEY}).status_code == 200
    page = client.get(f"/admin/journeys/{journey_id}")
    assert page.status_code == 200
    return page.text


def test_a_stopped_journey_keeps_the_report_of_the_stages_that_ran(stack):
    # A straight journey and no stored calibration: the real pipeline stops at calibrate, and
    # the journey waits for its camera with the reports of the stages that ran.
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        run.run_journey(journey_id, stack.settings)
        row = _row(stack, journey_id)
        assert (row.status, row.stage) == ("queued", "waiting_for_camera")
        report = [StageReport.from_json(r) for r in row.report]
        assert [r.stage for r in report] == ["turns", "calibrate"]
        assert report[-1].summary.startswith("failed: ") and "no turn" in report[-1].summary
        answer = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(key)).json()
        assert answer["report"] == row.report
        page = _page(client, journey_id)
    assert "What each stage did" in page
    assert html.escape(report[-1].summary, quote=False) in page


def test_a_done_journey_keeps_its_report_and_a_requeue_clears_it(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        result = made_result([("0", "stop", 49.0112, 8.4185, 114.0)])
        result.report = [StageReport("triangulate", "1 sign triangulated", ())]
        finish(stack, journey_id, result)
        assert _row(stack, journey_id).report == [
            {"stage": "triangulate", "summary": "1 sign triangulated", "details": []}]
        assert "1 sign triangulated" in _page(client, journey_id)
        with session_scope(stack.url) as session:
            session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                            .values(status="failed"))
        assert client.post(f"/admin/journeys/{journey_id}/retry").status_code == 200
    assert _row(stack, journey_id).report is None


def test_a_journey_processed_before_reports_existed_reads_plainly(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
        finish(stack, journey_id, made_result([]))
        with session_scope(stack.url) as session:  # as a row written before migration 0006
            session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                            .values(report=None))
        assert client.get(f"/api/v1/journeys/{journey_id}",
                          headers=auth(key)).json()["report"] is None
        page = _page(client, journey_id)
    assert "no report (processed before reports existed)" in page

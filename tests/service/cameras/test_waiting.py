"""A journey waiting for its camera, with the real job on the factory bundle (a straight road):
no sweep takes it for stuck, nothing runs it until it is woken, a wake that was lost is repaired
by the sweeps, a journey that decides to wait while its camera is being calibrated goes back to
the queue itself, and the dashboard shows it, retries it and registers its camera."""

from __future__ import annotations

from sqlalchemy import func, select, update

from app.service.db.models import CalibrationRow, JourneyRow
from app.service.db.session import session_scope
from app.service.jobs import cameras, state
from app.service.jobs.embedded import EmbeddedWorker
from tests.service.cameras.conftest import BODY, journey, new_camera, waiting
from tests.utils.stack import ADMIN_KEY


def test_a_waiting_journey_is_not_stuck_and_waits_to_be_woken(stack):
    camera_id = new_camera()
    fleet = stack.key("fleet")
    with stack.client() as client:
        journey_id = waiting(stack, client, fleet, camera_id)
    settings = stack.settings
    with session_scope(stack.url) as session:
        assert journey_id not in state.requeue_stale(session, 0.0, 3)
        assert journey_id not in state.queued_ids(session)
        assert state.claim(session, journey_id, 60, 3) is None  # a stray delivery runs nothing
    worker = EmbeddedWorker(settings)
    worker.sweep()
    assert journey_id not in worker._pending
    assert cameras.wake_calibrated(stack.url, settings, None) == []  # nothing to wake it with

    # A calibration registered, and its wake lost (the API died before it): the sweep wakes the
    # journey, once; the embedded worker's sweep then submits it, and it is claimable.
    cameras.register(stack.url, camera_id, cameras.Registration(**BODY), "test")
    submitted: list[str] = []
    assert cameras.wake_calibrated(stack.url, settings, submitted.append) == [journey_id]
    assert submitted == [journey_id]
    assert cameras.wake_calibrated(stack.url, settings, submitted.append) == []
    assert cameras.wake_waiting(stack.url, camera_id, None, submitted.append) == []
    row = journey(stack, journey_id)
    assert (row.status, row.stage, row.message, row.report) == ("queued", "requeued", None, None)
    worker.sweep()
    assert journey_id in worker._pending
    with session_scope(stack.url) as session:
        assert state.claim(session, journey_id, 60, 3) == 2
    with session_scope(stack.url) as session:  # the second trigger finds it running
        assert state.claim(session, journey_id, 60, 3) is None


def test_a_wake_only_takes_the_journeys_of_the_calibrations_size(sqlite):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        journey_id = waiting(sqlite, client, fleet, camera_id)
    assert cameras.wake_waiting(sqlite.url, camera_id, (640, 480), None) == []
    assert cameras.wake_waiting(sqlite.url, camera_id, (64, 48), None) == [journey_id]


def test_a_journey_about_to_wait_for_a_camera_calibrated_meanwhile_is_queued_again(sqlite):
    """The race the camera lock closes: the run was given no calibration, the camera got one
    while it ran; deciding to wait, it finds it and goes back to the queue instead."""
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        journey_id = waiting(sqlite, client, fleet, camera_id)
    with session_scope(sqlite.url) as session:
        session.execute(update(JourneyRow).where(JourneyRow.id == journey_id).values(stage=None))
    with session_scope(sqlite.url) as session:
        attempt = state.claim(session, journey_id, 60, 3)
    cameras.register(sqlite.url, camera_id, cameras.Registration(**BODY), "test")
    submitted: list[str] = []
    assert cameras.wait_for_camera(sqlite.url, journey_id, attempt, camera_id, (64, 48),
                                   "no turn", None, sqlite.settings, submitted.append) == "requeued"
    assert submitted == [journey_id]
    row = journey(sqlite, journey_id)
    assert (row.status, row.stage, row.message) == ("queued", "requeued", None)
    # A run that lost the journey meanwhile changes nothing.
    assert cameras.wait_for_camera(sqlite.url, journey_id, attempt, camera_id, (64, 48),
                                   "no turn", None, sqlite.settings, None) is None


def _sign_in(client) -> None:
    assert client.post("/admin/login", data={"key": ADMIN_KEY}).status_code == 200


def test_the_dashboard_shows_retries_and_resumes_a_waiting_journey(sqlite):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        journey_id = waiting(sqlite, client, fleet, camera_id)
        _sign_in(client)
        listing = client.get(f"/admin/journeys?camera={camera_id}").text
        row = listing.split(f'data-id="{journey_id}"')[1].split("</tr>")[0]
        assert "waiting_for_camera" in row and "waiting for a calibration of camera" in row
        assert 'class="retry"' in row
        page = client.get(f"/admin/journeys/{journey_id}").text
        assert "waiting for a calibration of camera" in page
        section = client.get("/admin/cameras").text.split(f"<h2>{camera_id}</h2>")[1]
        section = section.split("</section>")[0]
        assert "1 journey waits</strong>" in section and "No calibration yet." in section
        assert f'action="/admin/cameras/{camera_id}/calibration"' in section
        assert 'value="64"' in section and 'value="48"' in section  # its frames' size

        # Retry: it runs now (and, its camera still uncalibrated, would wait again).
        assert client.post(f"/admin/journeys/{journey_id}/retry",
                           follow_redirects=False).status_code == 303
        assert (journey(sqlite, journey_id).status, journey(sqlite, journey_id).stage) == (
            "queued", None)
        with session_scope(sqlite.url) as session:
            session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                            .values(stage="waiting_for_camera"))

        form = {k: str(v) for k, v in BODY.items()}
        refused = client.post(f"/admin/cameras/{camera_id}/calibration",
                              data={**form, "cx": "99", "fy": "x"})
        assert refused.status_code == 422
        assert "fy: not a number" in refused.text
        refused = client.post(f"/admin/cameras/{camera_id}/calibration", data={**form, "cx": "99"})
        assert refused.status_code == 422 and "cx: the principal point must be inside" in refused.text
        forged = client.post(f"/admin/cameras/{camera_id}/calibration", data=form,
                             headers={"Origin": "https://evil.example"})
        assert forged.status_code == 403
        with session_scope(sqlite.url) as session:
            assert session.scalar(select(func.count()).select_from(CalibrationRow)
                                  .where(CalibrationRow.camera_id == camera_id)) == 0

        done = client.post(f"/admin/cameras/{camera_id}/calibration",
                           data={**form, "sigma_fx": "0.5"}, follow_redirects=False)
        assert done.status_code == 303
        assert done.headers["location"] == f"/admin/cameras#camera-{camera_id}"
        row = journey(sqlite, journey_id)
        assert (row.status, row.stage) == ("queued", "requeued")  # woken, for the worker
        section = client.get("/admin/cameras").text.split(f"<h2>{camera_id}</h2>")[1]
        assert "Registered calibration (epoch 1, by\nSIGNMAP_ADMIN_KEY" in section
        assert "fx 0.5, fy 0, cx 0" in section
    with session_scope(sqlite.url) as session:
        registered = session.scalars(select(CalibrationRow)
                                     .where(CalibrationRow.camera_id == camera_id)).one()
    assert (registered.source, registered.fx, registered.sigma_fx) == ("registered", 55.0, 0.5)

"""Two real Celery worker processes on Redis + PostgreSQL fuse journeys of the same place at the
same time: the fusion lock leaves exactly one map sign per real sign."""

from __future__ import annotations

import secrets
import time

import numpy as np
import pytest
from sqlalchemy import func, select

from app.pipeline.bundle import read_bundle
from app.service.db.session import session_scope
from app.service.db.models import MapSignRow, MapSignMemberRow
from tests.utils.results import map_support as ms
from tests.utils.results.service_support import bf_zip
from tests.utils.stack import CeleryWorker, Stack, make_settings
from worker.celery_app import FUSE_JOURNEY, make_celery

pytestmark = pytest.mark.postgres


def _wait_ready(worker: CeleryWorker, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while " ready." not in worker.log_path.read_text(errors="replace"):
        if worker.proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"worker not ready: {worker.log_path.read_text()[-3000:]}")
        time.sleep(0.3)


def test_two_workers_fusing_one_place_at_once_make_one_map_sign_per_real_sign(
        tmp_path, own_pg_url, redis_url):
    stack = Stack("postgres", make_settings(tmp_path / "data", database_url=own_pg_url,
                                            broker_url=redis_url))
    (tmp_path / "b.zip").write_bytes(bf_zip())
    journey_data = read_bundle(tmp_path / "b.zip", tmp_path / "x", decode_images=False)
    world = ms.make_world(6)
    rng = np.random.default_rng(17)
    tag = secrets.token_hex(4)
    ids = [f"j-{tag}-{n}" for n in range(4)]
    for day, journey_id in enumerate(ids):  # stored by their jobs, not fused yet
        ms.store_only(stack.settings, journey_data, journey_id, day, ms.journey_result(world, rng))
    workers = [CeleryWorker(stack.settings, tmp_path / f"worker-{n}.log") for n in range(2)]
    try:
        for worker in workers:
            _wait_ready(worker)
        celery = make_celery(stack.settings)
        for journey_id in ids:  # released together
            celery.send_task(FUSE_JOURNEY, args=[journey_id], queue=stack.settings.celery_queue)
        deadline = time.monotonic() + 90
        while sum(w.log_path.read_text().count("map fusion after journey") for w in workers) < 4:
            assert time.monotonic() < deadline, [w.log_path.read_text()[-2000:] for w in workers]
            time.sleep(0.3)
    finally:
        for worker in workers:
            worker.stop()
    logs = [w.log_path.read_text() for w in workers]
    assert all("Traceback" not in log for log in logs), logs
    box = ms.fusion.Region.around([world.lat0], [world.lon0], 1000.0)
    with session_scope(stack.url) as session:
        rows = session.scalars(select(MapSignRow).where(
            MapSignRow.removed_at.is_(None), box.contains(MapSignRow.lat_deg, MapSignRow.lon_deg))).all()
        n_members = session.scalar(select(func.count()).select_from(MapSignMemberRow).where(
            MapSignMemberRow.map_sign_id.in_([r.id for r in rows])))
    assert len(rows) == 6 and all(r.n_journeys == 4 for r in rows)
    assert n_members == 24

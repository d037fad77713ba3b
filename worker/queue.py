"""The Celery implementation of the service's job queue (``app.service.jobs.queue.JobQueue``): the
API sends each accepted journey to the broker, where a ``signmap worker`` takes it."""

from __future__ import annotations

from app.settings import Settings
from worker.celery_app import RUN_JOURNEY, make_celery


class CeleryQueue:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.app = make_celery(settings)

    def start(self) -> None:
        pass

    def submit(self, journey_id: str) -> None:
        self.app.send_task(RUN_JOURNEY, args=[journey_id], queue=self.settings.celery_queue)

    def stop(self) -> None:
        self.app.close()

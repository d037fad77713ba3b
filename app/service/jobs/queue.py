"""How the API hands a journey to a worker: Celery when a broker is configured, else the embedded
worker in this process (or nobody, with ``embedded_worker`` off: uploads then stay queued)."""

from __future__ import annotations

from typing import Protocol

from app.settings import Settings


class JobQueue(Protocol):
    def start(self) -> None: ...

    def submit(self, journey_id: str) -> None: ...

    def stop(self) -> None: ...


class CeleryQueue:
    def __init__(self, settings: Settings):
        from worker.celery_app import make_celery

        self.settings = settings
        self.app = make_celery(settings)

    def start(self) -> None:
        pass

    def submit(self, journey_id: str) -> None:
        from worker.celery_app import RUN_JOURNEY

        self.app.send_task(RUN_JOURNEY, args=[journey_id], queue=self.settings.celery_queue)

    def stop(self) -> None:
        self.app.close()


class HoldQueue:
    """Accepts and keeps journeys queued in the database; a later embedded worker picks them up."""

    def start(self) -> None:
        pass

    def submit(self, journey_id: str) -> None:
        pass

    def stop(self) -> None:
        pass


def make_queue(settings: Settings) -> JobQueue:
    if settings.broker_url:
        return CeleryQueue(settings)
    if settings.embedded_worker:
        from app.service.jobs.embedded import EmbeddedWorker

        return EmbeddedWorker(settings)
    return HoldQueue()

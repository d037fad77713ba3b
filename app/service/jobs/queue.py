"""How the API hands a journey to a worker: the ``JobQueue`` interface, and the two queues that need
no broker: the embedded worker in this process, or nobody (``embedded_worker`` off: uploads then stay
queued in the database). The Celery queue (``worker.queue.CeleryQueue``) is chosen above this
package, where a broker is configured (``app.commands.service.create_service_app``)."""

from __future__ import annotations

from typing import Protocol

from app.settings import Settings


class JobQueue(Protocol):
    def start(self) -> None: ...

    def submit(self, journey_id: str) -> None: ...

    def stop(self) -> None: ...


class HoldQueue:
    """Accepts and keeps journeys queued in the database; a later embedded worker picks them up."""

    def start(self) -> None:
        pass

    def submit(self, journey_id: str) -> None:
        pass

    def stop(self) -> None:
        pass


def local_queue(settings: Settings) -> JobQueue:
    """The queue without a broker: the embedded worker, or HoldQueue with ``embedded_worker`` off."""
    if settings.embedded_worker:
        from app.service.jobs.embedded import EmbeddedWorker

        return EmbeddedWorker(settings)
    return HoldQueue()

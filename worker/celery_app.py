"""The Celery application: ``celery -A worker.celery_app worker`` (or ``signmap worker``).

Jobs are acknowledged only after they finish (``acks_late``) and given back to the queue when the
worker process dies (``reject_on_worker_lost``); each worker process runs and reserves one job at a time.
A killed worker's journey is also recovered from the database: see ``worker.tasks``.
"""

from __future__ import annotations

from celery import Celery
from celery.signals import after_setup_logger, after_setup_task_logger

from app import logs
from app.settings import Settings

RUN_JOURNEY = "signmap.run_journey"
FUSE_JOURNEY = "signmap.fuse_journey"


def make_celery(settings: Settings) -> Celery:
    app = Celery("signmap", broker=settings.broker_url, include=["worker.tasks"])
    app.conf.update(
        task_default_queue=settings.celery_queue,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_ignore_result=True,
        worker_prefetch_multiplier=1,
        worker_concurrency=1,
        # One job per worker process, run in its main thread: the pipeline spawns its own COLMAP
        # processes, which a daemonic prefork child may not. Scale with more worker processes.
        worker_pool="solo",
        # Redis hands an unacknowledged job to another worker after this long. It must exceed the
        # longest job; a dead worker's job is found sooner by the heartbeat sweep (worker.tasks).
        broker_transport_options={"visibility_timeout": settings.broker_visibility_timeout_s},
        broker_connection_retry_on_startup=True,
    )
    return app


@after_setup_logger.connect
@after_setup_task_logger.connect
def _escape_log_lines(logger, **_kwargs) -> None:
    # Celery sets up its own handlers; their lines are escaped as the service's are (app.logs).
    logs.install(logger)


settings = Settings()
app = make_celery(settings)

"""Running journeys: the one job (``run``), the journey row's life cycle (``state``), map fusion after
a journey (``fusion``), the queue interface the API submits to (``queue``: ``JobQueue`` and the
no-broker choices, ``embedded`` or holding), and the sweeps of crash leftovers (``sweep``). The
Celery implementation of ``JobQueue`` lives in ``worker/``, above this package."""

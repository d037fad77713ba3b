"""The HTTP service: the API, the operators' dashboard and the jobs they hand journeys to.

Layers, top to bottom: ``api/`` (routes of the wire contract) and ``admin/`` (the dashboard) take
their session and caller from ``deps.py`` and read and write through ``db/`` (rows, sessions,
``crud``, queries) and ``jobs/`` (the job, its row's life cycle, fusion, the queue interface);
``auth.py``, ``storage.py`` and ``startup.py`` serve them all; ``app.py`` assembles the app.
Import rules: a lower layer never imports a higher one, and nothing here imports ``worker`` (the
Celery side) or ``app.commands`` (the CLI): both sit above the service and compose it.
"""

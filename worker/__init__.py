"""The Celery worker of the service: ``celery_app`` (the application), ``queue`` (the job queue
the API sends journeys to) and ``tasks`` (running a journey, recovering those whose worker died)."""

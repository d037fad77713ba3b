"""End to end across the whole stack: rendered journeys uploaded to a running service (embedded or
PostgreSQL + Redis + Celery workers, one host or two), processed by COLMAP and mapped."""

"""The public HTTP API of the wire contract (base path /api/v1): one module of routes per resource
under ``routes/``, every response model in ``schemas.py``, and the streaming multipart receipt of an
upload in ``upload.py``. Routes get their database session and caller from ``app.service.deps`` and
leave row updates to ``app.service.db.crud``."""

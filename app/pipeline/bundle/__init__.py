"""Reading an uploaded journey bundle: the zip and its limits, the manifest, GPS (csv, gpx, EXIF),
detections and their association into tracks, checked against the wire contract
(docs/journey-format.md) into a ``types.Journey``.

Imports go down to ``geometry``, ``config`` and ``types`` only, never to ``steps``, ``colmap`` or
``run``. The entry points are re-exported here: ``read_bundle``, ``check_bundle``.
"""

from app.pipeline.bundle.read import FRAME_EXTENSIONS, check_bundle, read_bundle

__all__ = ["FRAME_EXTENSIONS", "check_bundle", "read_bundle"]

"""The journey pipeline: one uploaded bundle in, the signs it saw placed on the map out.

Layers, each importing only from the ones below it:

* ``run`` (``process_journey``) orchestrates the steps: the stages, their timings, progress and
  per-stage reports. Nothing else imports it but the callers outside the pipeline.
* ``steps`` are the stages by name (turns, plan, calibrate, ego_motion, align, place_signs).
* ``bundle`` reads and validates an upload into a ``types.Journey``; ``colmap`` is the
  structure-from-motion adapter (correspondences and mapping with pycolmap); ``geometry`` is the
  maths (geodesy, similarity, triangulation, uncertainty).
* ``types`` (the shared values and the conventions) and ``config`` (the knobs) are at the bottom.

The pipeline never imports ``app.service``, ``app.commands`` or ``worker``: they import it.
"""

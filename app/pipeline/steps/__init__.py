"""The pipeline's stages, one module each, named as ``run.process_journey`` reports them:
``turns`` (turns on the GPS track), ``plan`` (calibration candidates, sign passes, ego windows),
``calibrate`` (self-calibration), ``ego_motion`` (windows of camera motion), ``align`` (windows
to GPS) and ``place_signs`` (the triangulate stage); ``sign_tracks`` are the signs' detections
grouped per track and split into passes.

Steps import ``colmap``, ``geometry``, ``config``, ``types`` and earlier steps; only ``run``
imports the steps.
"""

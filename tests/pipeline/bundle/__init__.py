"""Reading a journey bundle (``app.pipeline.bundle``): the zip and its contract, the GPS fixes
(coverage, a receiver's stated accuracy) and the association of detections into tracks."""

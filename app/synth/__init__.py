"""Synthetic journeys: a seeded street world rendered exactly through a distorted camera.

``app.synth.journey`` is the entry point (``SynthConfig`` from ``config``, ``generate``,
``write_bundle``): ``street`` builds the world (road, layout, textures), ``drive`` moves the camera
along it and logs the GPS, ``camera`` renders the frames through the lens, adds the image effects
and makes the on-board detections, and ``bundle`` writes the wire contract's zip and
``truth.json``. ``corpus`` writes many varied journeys, drawn by ``draw``; ``video`` turns a
journey into the video bundle a dash cam fleet uploads (MP4, NMEA or GPX, a wrong clock). Never
imports the service.
"""

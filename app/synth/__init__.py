"""Synthetic journeys: a seeded street world rendered exactly through a distorted camera.

``app.synth.journey`` is the entry point (``SynthConfig`` from ``config``, ``generate``,
``write_bundle``); the world is built by ``world`` (from ``road``, ``layout``, ``textures``), packed
by ``scene`` and ray-cast by ``render`` (wide-angle lenses: ``lens``); ``speed`` and ``trajectory``
drive the camera and the GPS, ``detect`` makes the on-board detections, ``effects`` adds blur,
exposure changes and noise, ``bundle`` writes the wire contract's zip and ``truth.json``.
``corpus`` writes many varied journeys, drawn by ``draw`` (``draw_parts``). Never imports the
service.
"""

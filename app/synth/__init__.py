"""Synthetic journeys: a seeded street world rendered exactly through a distorted camera.

``app.synth.journey`` is the entry point (``SynthConfig``, ``generate``, ``write_bundle``); the
world is built by ``world`` (from ``road``, ``layout``, ``textures``), packed by ``scene`` and
ray-cast by ``render``; ``trajectory`` drives the camera and the GPS, ``detect`` makes the on-board
detections, ``bundle`` writes the wire contract's zip and ``truth.json``. Never imports the service.
"""

"""Signmap: traffic signs mapped from crowdsourced dashcam journeys. ``pipeline`` turns one
journey into georeferenced signs, ``fusion`` merges journeys into one map, ``service`` is the HTTP
API and dashboard, ``synth`` renders synthetic journeys, ``commands`` and ``cli`` are the
``signmap`` command line, ``settings`` and ``geojson`` are shared by them."""

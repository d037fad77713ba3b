"""Video journeys made from rendered ones, for tests and benches: frames encoded as a real H.264
MP4 (PyAV) with the camera's ``creation_time``, and the journey's GPS written as the logs a dash cam
fleet uploads (NMEA, GPX), on a GPS clock that disagrees with the camera's by a chosen offset."""

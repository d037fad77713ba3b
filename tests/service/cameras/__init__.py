"""Cameras the operator knows and journeys that wait for their camera (issue 66, items 4 and 6):
registering a calibration (API, dashboard, `signmap cameras`), the cameras API, the epochs, and
journeys without a turn that wait for their camera and resume once it is calibrated."""

"""The benchmark of the paper's tables: a fixed suite of synthetic journeys run by our pipeline,
with the true camera and by the naive COLMAP baseline (``signmap bench``), the camera-error
sensitivity study and map fusion over N journeys, and the metrics every accuracy bench scores a
run with against a synthetic journey's truth.
"""

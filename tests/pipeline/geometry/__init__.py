"""Geometry with no COLMAP (``app.pipeline.geometry``): geodesy, triangulation, facing, a sign's
uncertainty, the GPS noise estimate and smoothing spline, and the path-scale check."""

"""Ego-motion (``steps.ego_motion``, ``colmap.klt_features``): window planning, initial pairs and
the KLT tracks COLMAP maps from."""

"""Structure from motion with COLMAP (pycolmap): correspondences (COLMAP's SIFT, or KLT feature
tracks imported, ``klt_features``), the named COLMAP option presets (``presets``), mapping of
frame windows in child processes (``sfm``), stage-2 intrinsics refinement (``refine``) and one
stage's database and windows (``stage``).

Imports go down to ``geometry``, ``config`` and ``types``; never up to ``steps`` or ``run``.
Only this package knows COLMAP's pixel convention (centres at +0.5).
"""

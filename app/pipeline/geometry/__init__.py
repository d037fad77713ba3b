"""The maths of the pipeline, free of COLMAP and of the stages: geodesy (GPS <-> local metric
frames), similarity (Umeyama Sim(3) alignment), triangulation, facing, uncertainty and the GPS
noise estimate.

Modules here import numpy/scipy and ``app.pipeline.types`` only (and each other); everything
else in the pipeline may import them.
"""

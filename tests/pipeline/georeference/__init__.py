"""Aligning reconstructed windows to the GPS (``steps.align``, ``run.georeference``): similarity
fits, the joint alignment of chained windows, and the poses a sign's frames get."""

"""Self-calibration (``steps.calibrate``, ``colmap.refine``): how a candidate window is judged on
made-up results, stage 2 and its probe, the candidates' shared SIFT, and real COLMAP on varied
rendered journeys."""

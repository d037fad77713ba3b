"""Tests of the journey pipeline (``app.pipeline``), one subfolder per subject; the real pipeline
end to end on small rendered journeys (``test_run.py``) and its per-stage report here."""

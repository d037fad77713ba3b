"""The benchmarks: ``signmap bench`` and its sub-commands (``cli``), ``python -m bench.compare``.

paper: the fixed suite of synthetic journeys, its baselines, sensitivity and fusion studies, and
how a run is scored against a journey's truth; corpus: the pipeline over a generated corpus of
many journeys, its report and replays; studies: single questions asked of corpora and real
drives; service: load on the HTTP API, the map and the admin dashboard; cost: a worker step's
time per frame (the sign detector). Results: ``results/``.
"""

"""Pipeline results without the pipeline, as a worker would store them: signs and finished
journeys (``service_support``), a small synthetic map world (``map_support``), the dashboard's
seeded journeys (``dashboard_seed``); and comparisons of what the service answers with the truth."""

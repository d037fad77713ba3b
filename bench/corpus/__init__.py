"""``signmap bench corpus``: the pipeline over every journey of a generated corpus (a tuning half
to choose knobs on, a check half to confirm them), its report, before/after comparisons of runs,
and replays of the georeferencing stages on kept reconstructions.
"""

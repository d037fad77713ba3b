"""Tests of the benchmarks (bench/): the suite and fusion benches' reports, the corpus bench and
its report, the API load bench, and each study on small drawn or rendered journeys.
"""

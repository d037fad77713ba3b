"""The sign-uncertainty knob fit (bench/studies/uncertainty_fit.py) on signs whose errors are
drawn from a known model: it finds knobs that make the 95 % radii honest for both GPS kinds."""

from __future__ import annotations

import numpy as np

from app.pipeline.geometry.uncertainty import GeorefTerms
from bench.studies.uncertainty_fit import Knobs, SignTerms, coverage, fit, sign_terms


def _signs(rng, n: int, gps: str, rms_m: float, floor_m: float, quad_per_m: float
           ) -> list[SignTerms]:
    """Signs whose common GPS error is ``floor_m`` plus ``quad_per_m`` times the residual rms
    squared: a phone's grows faster than its scatter."""
    sigma = np.sqrt(floor_m**2 + (quad_per_m * rms_m**2) ** 2 + 0.03**2)
    errs = np.linalg.norm(rng.normal(0.0, sigma, (n, 2)), axis=1)
    return [SignTerms("tuning", gps, float(e), np.eye(2) * 0.03**2,
                      GeorefTerms(0.0, 1.0, rms_m**2)) for e in errs]


def test_fit_finds_knobs_that_cover_95_percent_where_a_floor_alone_cannot():
    rng = np.random.default_rng(4)
    signs = _signs(rng, 400, "oxts", 0.3, 0.1, 0.4) + _signs(rng, 400, "phone", 2.0, 0.1, 0.4)
    knobs = fit(signs)
    share, n = coverage(signs, knobs)
    assert n == 800 and 0.94 <= share <= 0.96, (knobs, share)
    # The phone-like errors need the term that follows the receiver (truth: 0.4 x 2^2 = 1.6 m),
    # and with it both kinds are honest.
    assert knobs.bias_quad_per_m * 2.0**2 >= 1.0, knobs
    for gps in ("oxts", "phone"):
        assert 0.92 <= coverage([s for s in signs if s.gps == gps], knobs)[0] <= 0.98, gps
    # A floor alone cannot be honest for both: the best one leaves a kind outside 90-98 %, and
    # one wide enough for the OXTS-like signs leaves the phone-like ones far outside.
    floor_only = fit(signs, quads_per_m=[0.0])
    assert not all(0.90 <= coverage([s for s in signs if s.gps == gps], floor_only)[0] <= 0.98
                   for gps in ("oxts", "phone")), floor_only
    assert coverage([s for s in signs if s.gps == "phone"], Knobs(0.3))[0] < 0.3
    assert coverage([s for s in signs if s.gps == "oxts"], Knobs(0.3))[0] > 0.95


def test_coverage_agrees_with_the_exact_radius_and_reads_bench_records():
    record = {"half": "check", "params": {"gps_white_sigma_m": 0.25, "gps_bias_sigma_m": 0.1},
              "sign_errors": {"7": {"h_err_m": 0.5, "cov_tri_h_m2": [[0.01, 0.0], [0.0, 0.04]],
                                    "georef_noise_m2": 0.01, "georef_floor_weight": 1.0,
                                    "georef_residual_m2": 0.09}}}
    (sign,) = sign_terms([record])
    assert (sign.half, sign.gps) == ("check", "oxts")
    for knobs in (Knobs(0.1), Knobs(0.2, 1.0, 0.5), Knobs(0.3, 1.0, 1.0)):
        exact_inside = sign.h_err_m <= sign.r95_m(knobs)
        assert coverage([sign], knobs)[0] == float(exact_inside), knobs

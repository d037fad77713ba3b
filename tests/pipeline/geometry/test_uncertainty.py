"""A sign's covariance and its 95 % horizontal radius (app.pipeline.geometry.uncertainty)."""

from __future__ import annotations

import numpy as np
import pytest

from app.pipeline.geometry.uncertainty import GeorefTerms, horizontal_radius_m


def test_radius_holds_95_percent_of_gaussian_samples():
    rng = np.random.default_rng(0)
    for cov in (np.diag([0.04, 0.04, 1.0]), np.diag([0.25, 0.0025, 1.0]),
                np.array([[0.09, 0.05, 0.0], [0.05, 0.05, 0.0], [0.0, 0.0, 1.0]])):
        r = horizontal_radius_m(cov)
        xy = rng.multivariate_normal(np.zeros(2), cov[:2, :2], size=200_000)
        assert np.mean(np.hypot(*xy.T) <= r) == pytest.approx(0.95, abs=0.003)
    # Circular: the chi-square quantile; a line: 1.96 sigma.
    assert horizontal_radius_m(np.diag([1.0, 1.0, 1.0])) == pytest.approx(np.sqrt(5.9915), rel=1e-4)
    assert horizontal_radius_m(np.diag([1.0, 1e-10, 1.0])) == pytest.approx(1.95996, rel=1e-3)


def test_georeferencing_adds_averaged_noise_and_the_floor():
    cov = GeorefTerms.of_alignment(alignment_rms_m=2.0, n_fixes=16).cov_m2(0.15, noise_gain=1.0)
    assert cov[0, 0] == pytest.approx(4.0 / 16 + 0.15**2)
    assert cov[2, 2] == pytest.approx(4 * cov[0, 0])
    assert GeorefTerms.of_alignment(0.3, 0).cov_m2(0.0, 1.0)[1, 1] == pytest.approx(0.09)
    # Two passes of weight 1/2 each: both terms halve.
    assert GeorefTerms(0.5, 0.5).cov_m2(0.2, 2.0)[0, 0] == pytest.approx(1.0 + 0.02)


def test_common_error_grows_with_the_square_of_the_residual_and_passes_combine():
    # One pass: residual 2 m, square 0.3 /m: common error 1.2 m per axis.
    one = GeorefTerms.of_alignment(alignment_rms_m=2.0, n_fixes=16)
    assert one.horizontal_m2(0.0, 1.0, 0.3) == pytest.approx(4.0 / 16 + 1.2**2)
    # The square term off: the averaged noise and the floor alone.
    assert one.horizontal_m2(0.1, 1.0) == pytest.approx(0.25 + 0.01)
    # Two agreeing passes of weight 1/2 (sum w^2 = 1/2): every term halves, the square included.
    two = GeorefTerms(0.5 * one.averaged_noise_m2, 0.5, 0.5 * one.residual_m2)
    assert two.horizontal_m2(0.1, 1.0, 0.3) == pytest.approx(
        0.5 * one.horizontal_m2(0.1, 1.0, 0.3))
    assert GeorefTerms(0.0, 0.0, 0.0).horizontal_m2(0.1, 1.0, 0.3) == 0.0

"""The robust information-form mean of a map sign's members, and the covariance floor."""

from __future__ import annotations

import numpy as np

from app.fusion.local import floor_covariance
from app.fusion.robust import robust_fuse


def test_single_member_is_returned_as_is():
    cov = np.array([[0.5, 0.1, 0.0], [0.1, 0.3, 0.0], [0.0, 0.0, 2.0]])
    fused = robust_fuse(np.array([[1.0, 2.0, 3.0]]), cov[None])
    np.testing.assert_allclose(fused.xyz_enu, [1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(fused.cov_enu, cov, atol=1e-12)
    assert fused.weights.tolist() == [1.0]


def test_each_axis_comes_from_the_member_that_is_precise_on_it():
    """A is sharp in east, B in north; symmetric, so their robust weights are equal and the mean
    is exactly the information-weighted one: (100 * 1 + 1 * 0) / 101 on both axes."""
    xyz = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    cov = np.array([np.diag([0.01, 1.0, 1.0]), np.diag([1.0, 0.01, 1.0])])
    fused = robust_fuse(xyz, cov)
    np.testing.assert_allclose(fused.xyz_enu, [100 / 101, 100 / 101, 0.0], atol=1e-12)
    assert fused.weights[0] == fused.weights[1]
    w = fused.weights[0]
    np.testing.assert_allclose(np.diag(fused.cov_enu), [1 / (101 * w), 1 / (101 * w), 0.5 / w],
                               rtol=1e-12)


def _five_inliers(seed=3):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0.0, 0.3, (5, 3))
    return xyz, np.repeat(np.eye(3)[None] * 0.09, 5, axis=0)


def test_one_bad_member_does_not_drag_the_sign():
    xyz, cov = _five_inliers()
    clean = robust_fuse(xyz, cov)
    bad = robust_fuse(np.vstack([xyz, [10.0, 0.0, 0.0]]), np.vstack([cov, cov[:1]]))
    # Plain information-weighted mean would move by 10 / 6 = 1.7 m.
    assert np.linalg.norm(bad.xyz_enu - clean.xyz_enu) < 0.05
    assert bad.weights[-1] < 0.01 and bad.weights[:-1].min() > 0.4
    assert bad.residuals[-1] > 30.0


def test_a_down_weighted_member_has_almost_no_say_and_scale_is_relative():
    xyz, cov = _five_inliers()
    clean = robust_fuse(xyz, cov)
    scale = np.array([1.0] * 5 + [1e-3])
    # 3 m off: within reach of Cauchy (weight ~0.5), so only the scale keeps it out.
    shifted = robust_fuse(np.vstack([xyz, [3.0, 0.0, 0.0]]), np.vstack([cov, cov[:1]]), scale)
    assert np.linalg.norm(shifted.xyz_enu - clean.xyz_enu) < 0.002
    # Only down-weighted members: the scale cancels, nothing is inflated.
    alone = robust_fuse(xyz, cov, np.full(5, 1e-3))
    np.testing.assert_array_equal(alone.xyz_enu, clean.xyz_enu)
    np.testing.assert_array_equal(alone.cov_enu, clean.cov_enu)


def test_covariance_floor_raises_only_small_eigenvalues():
    rot = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
    cov = rot @ np.diag([1e-4, 2.0, 0.0]) @ rot.T
    floored = floor_covariance(cov[None], 0.2)[0]
    np.testing.assert_allclose(np.linalg.eigvalsh(floored), [0.04, 0.04, 2.0], atol=1e-12)
    np.testing.assert_allclose(floored, rot @ np.diag([0.04, 2.0, 0.04]) @ rot.T, atol=1e-12)

"""The render check: the imagery of a rendered journey, matched and triangulated with the true
poses, fits the truth file's own camera best, and says so when the truth names another lens."""

import pytest

from bench.studies.render_check import check_bundle


def test_a_rendered_journey_fits_its_own_camera_best(turn_journey_bundle):
    bundle, truth = turn_journey_bundle
    scan = check_bundle(bundle, truth, n_pairs=4)
    assert scan.n_matches > 500
    assert scan.best_scale == pytest.approx(1.0, abs=0.002)
    assert min(scan.at(0.99), scan.at(1.01)) > 1.1 * scan.at(1.0)


def test_a_truth_naming_another_focal_length_is_caught(turn_journey_bundle):
    bundle, truth = turn_journey_bundle
    camera = {**truth["camera"], "fx": truth["camera"]["fx"] * 1.01,
              "fy": truth["camera"]["fy"] * 1.01}
    scan = check_bundle(bundle, {**truth, "camera": camera}, n_pairs=4)
    assert scan.best_scale == pytest.approx(1 / 1.01, abs=0.003)

"""``signmap bench gps-draws``: fresh draws of a suite journey's GPS noise, compared draw by
draw."""

from dataclasses import replace

import numpy as np
import pytest

from app.pipeline.geometry.geodesy import frame_at
from app.synth.config import SynthConfig
from bench.cli import main
from bench.gps_draws import draw_gps, table

TRUTH_FRAME = frame_at(48.1, 11.5, 520.0)
RECON_FRAME = frame_at(48.10003, 11.50004, 521.5)  # a noisy first fix some metres away


def _path(n=400):
    t = np.arange(n) / 10.0
    return np.column_stack([8.0 * t, 20.0 * np.sin(t / 5.0), np.full(n, 1.65)])


def test_a_noiseless_draw_is_the_truth_carried_into_the_reconstructions_frame():
    true_enu = _path()
    quiet = SynthConfig(gps_white_sigma_m=0.0, gps_bias_sigma_m=0.0, gps_alt_sigma_m=0.0)
    drawn = draw_gps(true_enu, quiet, TRUTH_FRAME, RECON_FRAME, seed=3)
    lat, lon, alt = TRUTH_FRAME.to_geodetic(true_enu)
    np.testing.assert_allclose(drawn.xyz_m, RECON_FRAME.to_local(lat, lon, alt), atol=1e-6)
    # The frames differ by metres: a draw left in the truth's frame would be caught here.
    assert np.linalg.norm(drawn.xyz_m - true_enu, axis=1).min() > 1.0


def test_draws_are_repeatable_by_seed_and_carry_the_configured_noise():
    true_enu = _path()
    cfg = SynthConfig(gps_white_sigma_m=0.5, gps_bias_sigma_m=0.0, gps_alt_sigma_m=1.0)
    quiet = draw_gps(true_enu, replace(cfg, gps_white_sigma_m=0.0, gps_alt_sigma_m=0.0),
                     TRUTH_FRAME, RECON_FRAME, seed=0).xyz_m
    a = draw_gps(true_enu, cfg, TRUTH_FRAME, RECON_FRAME, seed=1).xyz_m
    b = draw_gps(true_enu, cfg, TRUTH_FRAME, RECON_FRAME, seed=1).xyz_m
    c = draw_gps(true_enu, cfg, TRUTH_FRAME, RECON_FRAME, seed=2).xyz_m
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    horizontal = (a - quiet)[:, :2].std(axis=0)
    np.testing.assert_allclose(horizontal, 0.5, rtol=0.15)
    assert (a - quiet)[:, 2].std() == pytest.approx(1.0, rel=0.15)


def test_only_per_frame_gps_can_be_drawn_again():
    with pytest.raises(ValueError, match="one GPS position per frame"):
        draw_gps(_path(), SynthConfig(gps_rate_hz=1.0), TRUTH_FRAME, RECON_FRAME, seed=0)


def _rows(abs_median, journey="loop-300"):
    own = {"journey": journey, "draw": -1, "n_signs": 5, "n_false": 0, "abs_median_m": 9.0,
           "abs_mean_m": 9.0, "rel_mean_m": 9.0}
    return [own] + [{"journey": journey, "draw": k, "n_signs": 4 + k % 2, "n_false": 0,
                     "abs_median_m": v, "abs_mean_m": v, "rel_mean_m": v}
                    for k, v in enumerate(abs_median)]


def test_the_table_pairs_each_variants_draws_with_the_defaults():
    text = table("loop-300", {"defaults": _rows([0.3, 0.4, 0.5]),
                              "w80": _rows([0.2, 0.45, 0.4])})
    rows = [line for line in text.splitlines() if line.startswith("| w80 |")]
    assert rows[0] == ("| w80 | 4-5 | 0 | abs_median_m | 0.350 | 0.400 | 0.440 | 9.000 | "
                       "-0.050 ± 0.050 | 2/3 |")
    assert "over 3 fresh GPS draws" in text


def test_draws_of_several_journeys_are_pooled_and_paired_journey_by_journey():
    base = _rows([0.3, 0.4], "a") + _rows([0.5, 0.6], "b")
    # The variant's rows arrive in another order: pairing must follow (journey, draw).
    variant = list(reversed(_rows([0.2, 0.5], "a"))) + _rows([0.5, 0.5], "b")
    text = table("long-1000", {"defaults": base, "x": variant})
    assert "over 4 fresh GPS draws of 2 journeys (a, b)" in text
    row = next(line for line in text.splitlines() if line.startswith("| x |"))
    assert row.endswith("| -0.025 ± 0.048 | 2/4 |")
    assert "| b | x | 4-5 | 0.500 | 0.500 | 0.500 |" in text.splitlines()


def test_a_reseeded_suite_journey_is_the_same_kind_in_another_world():
    from bench.gps_draws import suite_spec

    spec, other = suite_spec("long-1000"), suite_spec("long-1000", 12)
    assert other.name == "long-1000-s12"
    assert (other.synth.seed, other.synth.world_seed) == (12, 12) != (spec.synth.seed,
                                                                      spec.synth.world_seed)
    assert other.synth.replace(seed=spec.synth.seed, world_seed=spec.synth.world_seed) == spec.synth


def test_a_bad_knob_or_journey_is_refused_before_anything_is_reconstructed(tmp_path):
    with pytest.raises(SystemExit, match="nonsense_knob"):
        main(["gps-draws", "--cache", str(tmp_path), "--variant", "x:nonsense_knob=1"])
    with pytest.raises(SystemExit, match="no suite journey 'nowhere'"):
        main(["gps-draws", "--cache", str(tmp_path), "--journey", "nowhere"])
    assert not any(tmp_path.iterdir())

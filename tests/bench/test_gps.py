"""The GPS studies: fresh draws of a suite journey's GPS noise compared draw by draw (``signmap
bench gps-draws``); the scale a window's GPS alignment gives on a corpus journey drawn without its
pixels (``gps-scale``); the GPS check of the focal length, where a trajectory whose rotations are
all too large by a factor (what a short focal length does to ego-motion) is recognised by that
factor (``gps-focal``)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.steps.ego_motion import WindowPoses
from app.synth.config import SynthConfig
from bench.cli import main
from bench.studies.gps_draws import draw_gps
from bench.studies.gps_draws import table as draws_table
from bench.studies.gps_focal import focal_evidence, unbent_centres
from bench.studies.gps_scale import journey_scales
from bench.studies.gps_scale import table as scale_table

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
    text = draws_table("loop-300", {"defaults": _rows([0.3, 0.4, 0.5]),
                              "w80": _rows([0.2, 0.45, 0.4])})
    rows = [line for line in text.splitlines() if line.startswith("| w80 |")]
    assert rows[0] == ("| w80 | 4-5 | 0 | abs_median_m | 0.350 | 0.400 | 0.440 | 9.000 | "
                       "-0.050 ± 0.050 | 2/3 |")
    assert "over 3 fresh GPS draws" in text


def test_draws_of_several_journeys_are_pooled_and_paired_journey_by_journey():
    base = _rows([0.3, 0.4], "a") + _rows([0.5, 0.6], "b")
    # The variant's rows arrive in another order: pairing must follow (journey, draw).
    variant = list(reversed(_rows([0.2, 0.5], "a"))) + _rows([0.5, 0.5], "b")
    text = draws_table("long-1000", {"defaults": base, "x": variant})
    assert "over 4 fresh GPS draws of 2 journeys (a, b)" in text
    row = next(line for line in text.splitlines() if line.startswith("| x |"))
    assert row.endswith("| -0.025 ± 0.048 | 2/4 |")
    assert "| b | x | 4-5 | 0.500 | 0.500 | 0.500 |" in text.splitlines()


def test_a_reseeded_suite_journey_is_the_same_kind_in_another_world():
    from bench.studies.gps_draws import suite_spec

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


def _turn(n: int, turn_deg: float, radius_m: float, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """(T_model_cam (n, 4, 4), xyz (n, 3)): a car driving 20 m straight, then a circular turn of
    ``turn_deg``, then 20 m straight; the reconstruction sees every heading change ``kappa``
    times too large and is expressed in a rotated, scaled model frame."""
    arc_m = np.radians(turn_deg) * radius_m
    s_m = np.linspace(0.0, 40.0 + arc_m, n)
    heading = np.radians(turn_deg) * np.clip((s_m - 20.0) / arc_m, 0.0, 1.0)
    ds = np.diff(s_m)

    def chain(h: np.ndarray) -> np.ndarray:
        steps = np.stack([np.cos(h[:-1]), np.sin(h[:-1]), np.zeros(n - 1)], axis=1) * ds[:, None]
        return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])

    xyz = chain(heading)
    xyz_seen = chain(kappa * heading)
    # Camera looking along the heading: z forward, x right, y down; ENU x east, z up.
    R_enu_cam = np.stack([
        Rotation.from_euler("z", kappa * h).as_matrix()
        @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
        for h in heading])
    R_model_enu = Rotation.from_euler("xyz", [20, -35, 110], degrees=True).as_matrix()
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R_model_enu @ R_enu_cam
    T[:, :3, 3] = 0.37 * xyz_seen @ R_model_enu.T + np.array([3.0, -1.0, 2.0])
    return T, xyz


def test_unbending_by_the_true_factor_restores_the_shape():
    T, xyz = _turn(60, 90.0, 15.0, 1.04)
    c = unbent_centres(T, 1.04)
    d_true = np.linalg.norm(xyz[:, None] - xyz[None], axis=2)
    d_unbent = np.linalg.norm(c[:, None] - c[None], axis=2) / 0.37
    np.testing.assert_allclose(d_unbent, d_true, atol=1e-6)


@pytest.mark.parametrize("kappa", [0.97, 1.0, 1.03])
def test_the_rotation_scale_is_found_under_gps_noise(kappa):
    rng = np.random.default_rng(5)
    windows, xyz_all = [], []
    for k, (turn_deg, radius_m) in enumerate([(90.0, 15.0), (60.0, 30.0)]):
        T, xyz = _turn(60, turn_deg, radius_m, kappa)
        windows.append(WindowPoses((60 * k, 60 * k + 60), np.arange(60 * k, 60 * k + 60), T))
        xyz_all.append(xyz + rng.normal(0.0, 0.2, xyz.shape))
    ev = focal_evidence(windows, np.vstack(xyz_all))
    assert ev is not None and ev.n_windows == 2
    assert ev.kappa == pytest.approx(kappa, abs=0.008)
    assert 0 < ev.kappa_std < 0.01
    assert ev.rms_best_m <= ev.rms_m


def test_straight_windows_are_no_evidence():
    T, xyz = _turn(40, 10.0, 50.0, 1.05)
    assert focal_evidence([WindowPoses((0, 40), np.arange(40), T)], xyz) is None


def test_gps_heading_follows_a_turn():
    from app.pipeline.config import PipelineConfig
    from bench.studies.gps_focal import gps_heading_deg

    _, xyz = _turn(120, 90.0, 15.0, 1.0)
    heading = gps_heading_deg(xyz, np.arange(120) * 0.1, PipelineConfig())
    assert abs(heading[-1] - heading[0]) == pytest.approx(90.0, abs=3.0)


def test_a_spline_between_1_hz_fixes_keeps_window_scales_that_lines_shrink():
    # Corpus c0018: OXTS-like fixes at 1 Hz, 15 m/s through a 25 m curve, only 7 fixes (too few to
    # tell their noise). Lines between them put one window 3.4 % short.
    j = journey_scales(18)
    assert (j.half, j.gps_kind) == ("tuning", "oxts")
    rms = {m: float(np.sqrt(np.mean(e**2))) for m, e in j.errors.items()}
    assert len(j.errors["lines"]) == len(j.errors["spline"]) >= 3
    assert np.abs(j.errors["lines"]).max() > 0.03
    assert rms["spline"] < 0.7 * rms["lines"]
    rows = scale_table([j]).splitlines()
    assert rows[0].startswith("| GPS | half | journeys | windows | method | rms |")
    assert any(r.startswith("| oxts | tuning | 1 | ") and "| spline |" in r for r in rows)

"""The GPS white-noise estimate (app/pipeline/geometry/gps_noise.py) and the reconstruction check it feeds
(app/pipeline/place_signs.check_reconstruction)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.geometry.gps_noise import MIN_FIXES_TO_JUDGE, white_noise_m
from app.pipeline.steps.place_signs import check_reconstruction
from app.pipeline.geometry.triangulation import TriangulationError


def _drive(rate_hz: float, sigma_m: float, seed: int, bias_m: float = 0.0):
    """60 s: 10 m/s east, a 90 deg turn of radius 15 m, north; fixes with white noise and a
    constant bias (which the estimate must not see)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 1.0 / rate_hz)
    s = 10.0 * t
    arc = 15.0 * np.pi / 2
    x = np.where(s < 200, s, np.where(s < 200 + arc, 200 + 15 * np.sin((s - 200) / 15), 215))
    y = np.where(s < 200, 0.0, np.where(s < 200 + arc, 15 - 15 * np.cos((s - 200) / 15),
                                        15 + s - 200 - arc))
    xy = np.stack([x, y], 1) + rng.normal(0.0, sigma_m, (len(t), 2)) + bias_m
    lat, lon, _ = frame_at(49.0, 8.4, 0.0).to_geodetic(np.column_stack([xy, np.zeros(len(t))]))
    return t, lat, lon


@pytest.mark.parametrize("rate_hz, sigma_m", [(1.0, 2.5), (2.0, 0.3), (10.0, 0.2), (5.0, 1.0)])
def test_white_noise_is_recovered_whatever_the_rate_and_a_bias_is_not_counted(rate_hz, sigma_m):
    est = [white_noise_m(*_drive(rate_hz, sigma_m, seed, bias_m=3.0)) for seed in range(5)]
    assert np.median(est) == pytest.approx(sigma_m, rel=0.25), est


def test_too_few_fixes_tell_nothing():
    t, lat, lon = _drive(1.0, 1.0, 0)
    assert white_noise_m(t[:9], lat[:9], lon[:9]) is None
    assert white_noise_m(t[:10], lat[:10], lon[:10]) is not None
    # Enough to judge a window by, not for the journey's other uses of its noise.
    assert white_noise_m(t[:6], lat[:6], lon[:6], min_fixes=MIN_FIXES_TO_JUDGE) is None
    assert white_noise_m(t[:7], lat[:7], lon[:7], min_fixes=MIN_FIXES_TO_JUDGE) is not None


def test_a_short_journeys_few_fixes_give_a_noise_to_judge_its_windows_by():
    """Seven to nine fixes (a few seconds through a turn): the estimate scatters, but over many
    draws it is not small where the fixes are noisy (the check allows 5 times it)."""
    est = np.array([white_noise_m(*(a[40:48] for a in _drive(2.0, 1.0, seed)),
                                  min_fixes=MIN_FIXES_TO_JUDGE) for seed in range(40)])
    assert np.median(est) == pytest.approx(1.0, rel=0.35)
    assert np.quantile(est, 0.05) > 0.4


def test_a_journey_with_few_fixes_is_judged_by_their_own_noise():
    from app.pipeline.steps.place_signs import alignment_limit_m, judging_noise_m
    from app.pipeline.types import GpsTrack, Journey

    t, lat, lon = _drive(2.0, 1.0, 3)

    def journey(rows: slice) -> Journey:
        # As the bundle reader leaves a journey whose fixes are too few to give its noise.
        return Journey("cam", [], lat[rows], lon[rows], np.zeros(len(t[rows])), [], 1280, 720,
                       gps_fixes=GpsTrack(t[rows], lat[rows], lon[rows], np.zeros(len(t[rows]))))

    noise = judging_noise_m(journey(slice(40, 49)))  # 9 fixes through the turn
    assert 0.4 < noise < 2.5
    # A window 15 m rms off its GPS is broken by that limit (5 x the noise, at least 1 m).
    assert alignment_limit_m(noise, PipelineConfig()) < 15.0
    assert judging_noise_m(journey(slice(0, 5))) is None
    assert judging_noise_m(replace(journey(slice(0, 5)), gps_noise_m=0.3)) == 0.3


def test_a_reconstruction_far_off_its_gps_is_rejected_with_the_reason():
    config = PipelineConfig()  # 5 x the GPS noise, never below 1 m
    check_reconstruction(1.2, 0.3, config)    # 4 x: a good window with drifting GPS
    check_reconstruction(0.9, 0.1, config)    # 9 x, but under 1 m: decimetres are fine
    check_reconstruction(50.0, None, config)  # the noise is unknown: nothing to compare with
    with pytest.raises(TriangulationError, match=r"disagrees with the GPS by 1\.86 m rms, more "
                                                 r"than 5 x the GPS's own noise \(0\.22 m\)"):
        check_reconstruction(1.86, 0.22, config)


def test_a_journeys_gps_csv_carries_its_noise_to_the_frames():
    from app.pipeline.bundle.gps import gps_from_csv

    t, lat, lon = _drive(2.0, 0.5, 1)
    ids = [f"{i:06d}" for i in range(len(t))]
    rows = "\n".join(f"{f},{ti:.3f},{la:.9f},{lo:.9f}," for f, ti, la, lo in zip(ids, t, lat, lon))
    frame_gps = gps_from_csv("frame,timestamp_s,lat,lon,alt_m\n" + rows + "\n", ids)
    assert frame_gps.noise_m == pytest.approx(0.5, rel=0.3)

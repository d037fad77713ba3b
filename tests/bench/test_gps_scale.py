"""``signmap bench gps-scale``: the scale a window's GPS alignment gives, on a corpus journey drawn
without its pixels."""

import numpy as np

from bench.gps_scale import journey_scales, table


def test_a_spline_between_1_hz_fixes_keeps_window_scales_that_lines_shrink():
    # Corpus c0018: OXTS-like fixes at 1 Hz, 15 m/s through a 25 m curve, only 7 fixes (too few to
    # tell their noise). Lines between them put one window 3.4 % short.
    j = journey_scales(18)
    assert (j.half, j.gps_kind) == ("tuning", "oxts")
    rms = {m: float(np.sqrt(np.mean(e**2))) for m, e in j.errors.items()}
    assert len(j.errors["lines"]) == len(j.errors["spline"]) >= 3
    assert np.abs(j.errors["lines"]).max() > 0.03
    assert rms["spline"] < 0.7 * rms["lines"]
    rows = table([j]).splitlines()
    assert rows[0].startswith("| GPS | half | journeys | windows | method | rms |")
    assert any(r.startswith("| oxts | tuning | 1 | ") and "| spline |" in r for r in rows)

"""fuse_map on synthetic journeys: order independence, one map sign per real sign, accuracy,
journey bias, separation of close signs, class majority, missing altitudes."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from app.fusion import FusionConfig, JourneySign, fuse_map
from app.pipeline.geometry.geodesy import frame_at

ORIGIN = (49.0110123, 8.4183456, 112.3)
FRAME = frame_at(*ORIGIN)
T0 = 1_700_000_000.0
# Eight real signs along a road (ENU metres at ORIGIN): both sides, four classes.
TRUE_ENU = np.array([[25.0 * i, 5.0 if i % 2 else -5.0, 2.5 + 0.1 * i] for i in range(8)])
TRUE_CLS = ["stop", "yield", "speed_50", "no_entry"] * 2


def journey_key(j: int) -> str:
    return hashlib.sha256(f"journey-{j}".encode()).hexdigest()


def journey(j: int, rng, *, noise_m=0.3, bias_enu=(0.0, 0.0, 0.0), true_enu=TRUE_ENU,
            classes=TRUE_CLS, alt=True, cov_std_m=None, key=None) -> list[JourneySign]:
    """Journey j's signs: the true positions plus per-sign noise plus a journey-wide bias."""
    xyz = true_enu + rng.normal(0.0, noise_m, true_enu.shape) + np.asarray(bias_enu)
    lat, lon, alt_m = FRAME.to_geodetic(xyz)
    std = noise_m if cov_std_m is None else cov_std_m
    return [JourneySign(sign_id=f"j{j}:t{t}", journey_key=key or journey_key(j), cls=classes[t],
                        lat_deg=float(lat[t]), lon_deg=float(lon[t]),
                        alt_m=float(alt_m[t]) if alt else None,
                        cov_enu=np.eye(3) * std ** 2, captured_at=T0 + 86400.0 * j)
            for t in range(len(xyz))]


def enu(sign) -> np.ndarray:
    return FRAME.to_local(sign.lat_deg, sign.lon_deg, sign.alt_m)[0]


def track_of(sign_id: str) -> int:
    return int(sign_id.split(":t")[1])


def by_track(result) -> dict[int, object]:
    """The map sign holding each real sign's observations; fails on splits or mixtures."""
    out = {}
    for m in result.signs:
        tracks = {track_of(i) for i in m.members}
        assert len(tracks) == 1, f"map sign mixes real signs {tracks}"
        (t,) = tracks
        assert t not in out, f"real sign {t} split into several map signs"
        out[t] = m
    return out


@pytest.fixture(scope="module")
def five_journeys() -> list[JourneySign]:
    rng = np.random.default_rng(7)
    return [s for j in range(5) for s in journey(j, rng)]


@pytest.mark.parametrize("extra", ["none", "biased_and_no_altitude"])
def test_any_input_order_gives_the_identical_map(five_journeys, extra):
    signs = list(five_journeys)
    if extra != "none":
        rng = np.random.default_rng(8)
        signs += journey(5, rng, bias_enu=(0.0, 9.0, 1.0)) + journey(6, rng, alt=False)[:5]
    reference = fuse_map(signs)
    assert len(reference.signs) == 8
    assert set(reference.biased_journeys) == ({journey_key(5)} if extra != "none" else set())
    rng = np.random.default_rng(11)
    for _ in range(4):
        shuffled = [signs[i] for i in rng.permutation(len(signs))]
        again = fuse_map(shuffled)
        assert [m.map_id for m in again.signs] == [m.map_id for m in reference.signs]
        for a, b in zip(again.signs, reference.signs):
            assert a.members == b.members and a.cls == b.cls
            assert (a.lat_deg, a.lon_deg, a.alt_m) == (b.lat_deg, b.lon_deg, b.alt_m)
            assert np.array_equal(a.cov_enu, b.cov_enu)
        assert again.origin_lat_lon_alt == reference.origin_lat_lon_alt
        assert again.biased_journeys == reference.biased_journeys


def test_one_map_sign_per_real_sign_and_fusion_beats_single_journeys(five_journeys):
    result = fuse_map(five_journeys)
    assert result.biased_journeys == {}
    signs = by_track(result)
    assert sorted(signs) == list(range(8))
    single_err = [np.linalg.norm(enu(s) - TRUE_ENU[track_of(s.sign_id)]) for s in five_journeys]
    fused_err = [np.linalg.norm(enu(m) - TRUE_ENU[t]) for t, m in signs.items()]
    print(f"mean error: single journey {np.mean(single_err):.3f} m, fused {np.mean(fused_err):.3f} m")
    assert np.mean(fused_err) < 0.6 * np.mean(single_err)
    for t, m in signs.items():
        assert m.cls == TRUE_CLS[t] and m.n_observations == 5 and len(m.journeys) == 5
        assert (m.first_seen_at, m.last_seen_at) == (T0, T0 + 4 * 86400.0)
        assert m.state == "confirmed" and m.alt_m is not None
        # Five members of 0.3 m relative + 1 m GPS: sqrt(1.09 / 5) = 0.467 m, a little more as
        # Cauchy weights of inliers are below 1.
        assert 0.466 < np.sqrt(m.cov_enu[0, 0]) < 0.56


def test_map_ids_survive_adding_a_later_journey(five_journeys):
    before = {m.map_id for m in fuse_map(five_journeys).signs}
    later = journey(9, np.random.default_rng(3))
    assert {m.map_id for m in fuse_map(five_journeys + later).signs} == before


@pytest.mark.parametrize("rank", [0, 2, 5])
def test_a_biased_journey_is_flagged_and_does_not_move_the_map(five_journeys, rank):
    """Five honest journeys plus one whose GPS was 10 m off, first, middle or last in canonical
    order (the order journeys are associated in)."""
    keys = sorted(journey_key(j) for j in range(5))
    key_bad = {0: "0" * 64, 2: keys[1] + "0", 5: "f" * 64}[rank]
    j_bad = 5
    bias = np.array([8.0, -6.0, 0.0])
    biased = journey(j_bad, np.random.default_rng(5), bias_enu=bias, key=key_bad)
    assert sorted(keys + [key_bad]).index(key_bad) == rank

    alone = by_track(fuse_map(five_journeys))
    result = fuse_map(five_journeys + biased)
    fused = by_track(result)
    assert sorted(fused) == list(range(8))  # no duplicate map signs
    assert set(result.biased_journeys) == {key_bad}
    flag = result.biased_journeys[key_bad]
    assert np.linalg.norm(np.array(flag.offset_enu_m) - bias) < 0.5
    assert flag.n_journeys == 5
    for t in range(8):
        assert f"j{j_bad}:t{t}" in fused[t].members
        assert fused[t].evidence["biased_members"] == [f"j{j_bad}:t{t}"]
        moved_m = np.linalg.norm(enu(fused[t]) - enu(alone[t]))
        assert moved_m < 0.2, (t, moved_m)


def test_a_fully_biased_sign_keeps_its_corrected_position():
    """Signs seen only by a flagged journey are placed at its corrected (de-biased) position."""
    rng = np.random.default_rng(21)
    honest = [s for j in range(3) for s in journey(j, rng, true_enu=TRUE_ENU[:6],
                                                     classes=TRUE_CLS[:6])]
    bias = np.array([0.0, 12.0, 0.0])
    biased = journey(3, rng, bias_enu=bias, noise_m=0.1)
    result = fuse_map(honest + biased)
    assert set(result.biased_journeys) == {journey_key(3)}
    signs = by_track(result)
    for t in (6, 7):
        assert signs[t].members == [f"j3:t{t}"]
        assert np.linalg.norm(enu(signs[t]) - TRUE_ENU[t]) < 0.6


def _pair_journeys(second_enu, second_cls, n=5, seed=1):
    true_enu = np.array([[0.0, 6.0, 2.5], second_enu])
    rng = np.random.default_rng(seed)
    return [s for j in range(n)
            for s in journey(j, rng, true_enu=true_enu, classes=["stop", second_cls])]


def test_different_classes_one_metre_apart_stay_separate():
    result = fuse_map(_pair_journeys([1.0, 6.0, 2.5], "yield"))
    signs = by_track(result)
    assert sorted(signs) == [0, 1]
    assert (signs[0].cls, signs[1].cls) == ("stop", "yield")
    assert all(m.n_observations == 5 for m in result.signs)


def test_same_class_six_metres_apart_stay_separate():
    result = fuse_map(_pair_journeys([6.0, 6.0, 2.5], "stop"))
    signs = by_track(result)
    assert sorted(signs) == [0, 1]
    assert all(m.n_observations == 5 for m in result.signs)


def test_overconfident_inputs_still_associate():
    """Claimed 1 cm, true 0.3 m: the covariance floor alone (no GPS term) keeps them together."""
    rng = np.random.default_rng(4)
    signs = [s for j in range(5) for s in journey(j, rng, cov_std_m=0.01)]
    assert len(by_track(fuse_map(signs))) == 8
    relative_only = dict(journey_abs_std_m=0.0, journey_abs_up_std_m=0.0)
    assert len(by_track(fuse_map(signs, config=FusionConfig(**relative_only)))) == 8
    floorless = FusionConfig(cov_floor_std_m=0.01, **relative_only)
    assert len(fuse_map(signs, config=floorless).signs) > 8


def test_journeys_with_ordinary_gps_errors_share_map_signs():
    """Each journey off by ~1 m (normal GPS): one map sign per real sign, nobody flagged."""
    rng = np.random.default_rng(2)
    signs = [s for j in range(6)
             for s in journey(j, rng, bias_enu=np.r_[rng.normal(0.0, 0.7, 2), 0.0])]
    result = fuse_map(signs)
    assert len(by_track(result)) == 8 and result.biased_journeys == {}
    # Without the GPS term (and without bias correction) the chi-square gate splits them.
    relative_only = FusionConfig(journey_abs_std_m=0.0, journey_abs_up_std_m=0.0,
                                 bias_min_offset_m=1e9)
    assert len(fuse_map(signs, config=relative_only).signs) > 8


def test_class_majority_when_classes_may_differ():
    rng = np.random.default_rng(9)
    signs = [s for j in range(5) for s in journey(
        j, rng, true_enu=TRUE_ENU[:1],
        classes=["speed_60" if j in (1, 3) else "speed_50"])]
    strict = fuse_map(signs)
    assert sorted((m.cls, m.n_observations) for m in strict.signs) == [("speed_50", 3),
                                                                      ("speed_60", 2)]
    (merged,) = fuse_map(signs, config=FusionConfig(require_same_class=False)).signs
    assert merged.cls == "speed_50" and merged.n_observations == 5


def test_signs_without_altitude_take_it_from_those_with_one():
    rng = np.random.default_rng(12)
    signs = [s for j in range(4) for s in journey(j, rng, alt=j < 2)]
    signs_flat = by_track(fuse_map(signs))
    assert len(signs_flat) == 8
    for t, m in signs_flat.items():
        assert m.n_observations == 4
        assert abs(m.alt_m - (ORIGIN[2] + TRUE_ENU[t, 2])) < 0.6
    no_alt = [s for j in range(3) for s in journey(j, rng, alt=False)]
    result = fuse_map(no_alt)
    assert len(result.signs) == 8 and all(m.alt_m is None for m in result.signs)
    for m in result.signs:
        t = track_of(m.members[0])
        assert np.linalg.norm(enu(m)[:2] - TRUE_ENU[t, :2]) < 0.6


def test_empty_and_invalid_inputs():
    assert fuse_map([]).signs == []
    sign = journey(0, np.random.default_rng(0))[0]
    with pytest.raises(ValueError):
        fuse_map([sign, sign])


def test_a_sign_split_by_association_order_is_merged():
    """The first two journeys see one sign 3.5 m apart (beyond the 3 m gate), so association opens
    two map signs; the later journeys settle in between and the merge pass joins them."""
    rng = np.random.default_rng(6)
    first = np.array([[-1.75, 0.0, 0.0], [1.75, 0.0, 0.0]])
    signs = []
    for j in range(6):
        offset = first[j] if j < 2 else rng.normal(0.0, 0.05, 3)
        signs += journey(j, rng, noise_m=0.0, true_enu=TRUE_ENU[:1] + offset, key=f"k{j}",
                         cov_std_m=0.3)
    (merged,) = fuse_map(signs).signs
    assert merged.n_observations == 6
    assert np.linalg.norm(enu(merged) - TRUE_ENU[0]) < 0.5

"""Map fusion through the job's own store+fuse functions, on SQLite and PostgreSQL: order
independence, one map sign per real sign, accuracy, a GPS-biased journey, change detection,
journey deletion and the calibration flag."""

from __future__ import annotations

import secrets

import numpy as np
import pytest
from sqlalchemy import select

from app.pipeline.bundle import read_bundle
from app.service.jobs import fusion
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow, JourneySignRow, MapSignRow, MapSignMemberRow
from tests.utils.results import map_support as ms
from tests.utils.results.service_support import bf_zip


@pytest.fixture(scope="module")
def journey_data(tmp_path_factory):
    work = tmp_path_factory.mktemp("bundle")
    (work / "b.zip").write_bytes(bf_zip())
    return read_bundle(work / "b.zip", work / "x", decode_images=False)


def live_map(stack, world: ms.World) -> list[tuple]:
    """(id, class, lat, lon, alt, n_journeys, n_observations, state, members) of the live map signs
    near ``world``."""
    box = fusion.Region.around([world.lat0], [world.lon0], 1000.0)
    with session_scope(stack.url) as session:
        rows = session.scalars(select(MapSignRow).where(
            MapSignRow.removed_at.is_(None), box.contains(MapSignRow.lat_deg, MapSignRow.lon_deg))
            .order_by(MapSignRow.id)).all()
        members = {r.id: sorted(session.scalars(select(MapSignMemberRow.journey_sign_id).where(
            MapSignMemberRow.map_sign_id == r.id))) for r in rows}
    return [(r.id, r.cls, r.lat_deg, r.lon_deg, r.alt_m, r.n_journeys, r.n_observations, r.state,
             members[r.id]) for r in rows]


def true_track(world: ms.World, sign: tuple) -> str:
    """The real sign a map sign stands for: the nearest of its class."""
    return min((t for t, s in world.signs.items() if s[0] == sign[1]),
               key=lambda t: world.error_m(t, sign[2], sign[3], sign[4]))


def test_any_order_gives_the_same_map_one_sign_per_real_sign_and_better_than_one_journey(
        stack, journey_data):
    world = ms.make_world(6)
    rng = np.random.default_rng(7)
    results = [ms.journey_result(world, rng) for _ in range(5)]
    tag = secrets.token_hex(4)
    ids = [f"j-{tag}-{n}" for n in range(5)]
    maps = []
    for order in ([0, 1, 2, 3, 4], [3, 0, 4, 2, 1]):
        for n in order:
            ms.insert_done_journey(stack.settings, journey_data, ids[n], n, results[n])
        maps.append(live_map(stack, world))
        for n in order:
            assert fusion.delete_journey(stack.url, ids[n], stack.settings)
        assert live_map(stack, world) == []
    assert maps[0] == maps[1]
    fused = maps[0]
    assert len(fused) == 6 and sorted(true_track(world, s) for s in fused) == sorted(world.signs)
    assert all(s[5] == 5 and s[6] == 5 and s[7] == "confirmed" for s in fused)
    fused_err = np.mean([world.error_m(true_track(world, s), *s[2:5]) for s in fused])
    single_err = np.mean([world.error_m(s.track_id, s.lat_deg, s.lon_deg, s.alt_m)
                          for r in results for s in r.signs])
    assert fused_err < single_err, (fused_err, single_err)


def test_a_journey_with_a_10_m_gps_bias_barely_moves_the_map(stack, journey_data):
    world = ms.make_world(6)
    rng = np.random.default_rng(11)
    tag = secrets.token_hex(4)
    for n in range(5):
        ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-{n}", n,
                               ms.journey_result(world, rng))
    before = live_map(stack, world)
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-b", 5,
                           ms.journey_result(world, rng, offset_enu_m=(8.0, 6.0, 0.0)))
    after = live_map(stack, world)
    assert [s[0] for s in after] == [s[0] for s in before]
    frame = world.frame
    for b, a in zip(before, after):
        moved = frame.to_local([a[2]], [a[3]], [a[4]])[0] - frame.to_local([b[2]], [b[3]], [b[4]])[0]
        assert np.linalg.norm(moved) < 0.2, moved
    assert all(s[5] == 6 for s in after)  # the biased journey's signs joined the right map signs


def test_a_sign_missed_by_the_last_3_passes_is_possibly_removed_and_a_late_one_new(
        stack, journey_data):
    world = ms.make_world(6)
    rng = np.random.default_rng(3)
    tag = secrets.token_hex(4)
    for day in range(6):
        # Sign 0 was taken down after day 2; sign 5 was put up after day 2.
        skip = ("5",) if day < 3 else ("0",)
        ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-{day}", day,
                               ms.journey_result(world, rng, skip=skip))
    states = {true_track(world, s): s[7] for s in live_map(stack, world)}
    assert states == {"0": "possibly_removed", "1": "confirmed", "2": "confirmed",
                      "3": "confirmed", "4": "confirmed", "5": "new"}


def test_deleting_a_journey_refuses_its_region(stack, journey_data):
    world = ms.make_world(3)
    rng = np.random.default_rng(5)
    tag = secrets.token_hex(4)
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-0", 0,
                           ms.journey_result(world, rng))
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-1", 1,
                           ms.journey_result(world, rng, only=("0",)))
    assert [s[5] for s in live_map(stack, world)] == [2 if true_track(world, s) == "0" else 1
                                                      for s in live_map(stack, world)]
    assert fusion.delete_journey(stack.url, f"j-{tag}-0", stack.settings)
    remaining = live_map(stack, world)
    assert len(remaining) == 1 and remaining[0][8] == [f"j-{tag}-1:0"]
    assert not fusion.delete_journey(stack.url, f"j-{tag}-0", stack.settings)


@pytest.mark.parametrize("fx_factor, flagged", [(1.05, True), (1.01, False)])
def test_a_self_calibration_far_from_the_stored_one_is_flagged(stack, journey_data, fx_factor,
                                                               flagged):
    world = ms.make_world(2)
    stored = ms.CAMERA.__class__(**{**ms.CAMERA.__dict__, "fx": ms.CAMERA.fx * fx_factor})
    journey_id = f"j-{secrets.token_hex(4)}"
    ms.insert_done_journey(stack.settings, journey_data, journey_id, 0,
                           ms.journey_result(world, np.random.default_rng(1)), known_camera=stored)
    with session_scope(stack.url) as session:
        flag = session.get(JourneyRow, journey_id).calibration_flag
    if flagged:
        assert flag["reason"] == "self-calibration differs from the stored one in fx"
        assert flag["relative_deviation"]["fx"] == pytest.approx(0.05 / 1.05, abs=1e-5)
    else:
        assert flag is None


def test_a_journey_being_rerun_drops_out_of_the_map_until_it_is_done(stack, journey_data):
    world = ms.make_world(3)
    rng = np.random.default_rng(9)
    tag = secrets.token_hex(4)
    for day in range(2):
        ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-{day}", day,
                               ms.journey_result(world, rng))
    with session_scope(stack.url) as session:  # claimed again by a re-run: its signs stay stored
        session.get(JourneyRow, f"j-{tag}-0").status = "running"
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-2", 2,
                           ms.journey_result(world, rng))
    fused = live_map(stack, world)
    assert len(fused) == 3 and all(s[5] == 2 for s in fused)
    assert all(not any(m.startswith(f"j-{tag}-0:") for m in s[8]) for s in fused)


def test_a_journey_reads_done_only_once_the_map_holds_its_signs(stack, journey_data, monkeypatch):
    # A client polls the journey and then asks the map: the store and the fusion must commit
    # together, or it can read "done" and find no map sign of it.
    world = ms.make_world(3)
    journey_id = f"j-{secrets.token_hex(4)}"
    seen_while_fusing = []
    fuse_region = fusion.fuse_region

    def fuse_and_look_from_outside(session, region, settings):
        with session_scope(stack.url) as other:
            seen_while_fusing.append(other.get(JourneyRow, journey_id).status)
        return fuse_region(session, region, settings)

    monkeypatch.setattr(fusion, "fuse_region", fuse_and_look_from_outside)
    ms.insert_done_journey(stack.settings, journey_data, journey_id, 0,
                           ms.journey_result(world, np.random.default_rng(2)))
    assert seen_while_fusing == ["running"]
    assert len(live_map(stack, world)) == 3


def test_a_failed_fusion_still_stores_the_journey_and_the_next_fusion_has_it(
        stack, journey_data, monkeypatch):
    world = ms.make_world(3)
    rng = np.random.default_rng(4)
    tag = secrets.token_hex(4)

    def broken_fusion(session, region, settings):
        raise RuntimeError("fusion broke")

    monkeypatch.setattr(fusion, "fuse_region", broken_fusion)
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-0", 0,
                           ms.journey_result(world, rng))
    with session_scope(stack.url) as session:
        assert session.get(JourneyRow, f"j-{tag}-0").status == "done"
        assert len(session.scalars(select(JourneySignRow).where(
            JourneySignRow.journey_id == f"j-{tag}-0")).all()) == 3
    assert live_map(stack, world) == []
    monkeypatch.undo()
    ms.insert_done_journey(stack.settings, journey_data, f"j-{tag}-1", 1,
                           ms.journey_result(world, rng))
    assert [s[5] for s in live_map(stack, world)] == [2, 2, 2]

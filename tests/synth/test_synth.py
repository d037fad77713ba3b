"""The synthetic journey generator: determinism, the renderer against the camera model, detections
against the truth, trajectories, and the bundle against the wire contract."""

from __future__ import annotations

import csv
import io
import json
import zipfile
from xml.etree import ElementTree as ET

import cv2
import numpy as np
import piexif
import pytest

from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.types import CameraModel
from app.synth.bundle import manifest as synth_manifest
from app.synth.camera.render import _sample, camera_rays, first_hits, render_frame
from app.synth.camera.scene import _atlas, build_scene
from app.synth.drive.trajectory import noisy_gps
from app.synth.journey import KITTI_LIKE_CAMERA, SynthConfig, generate, write_bundle
from app.synth.street.world import build_world

# A third of the KITTI-like camera's resolution, same lens: fast to render.
SMALL_CAMERA = CameraModel(width=414, height=125, fx=959.2 / 3, fy=952.9 / 3,
                           cx=(694.4 + 0.5) / 3 - 0.5, cy=(241.7 + 0.5) / 3 - 0.5,
                           k1=-0.369, k2=0.158)


@pytest.fixture(scope="module")
def base_cfg() -> SynthConfig:
    return SynthConfig(world_seed=4, seed=1, n_frames=12, turns=1, camera=SMALL_CAMERA,
                       world_travel_m=96.0)


@pytest.fixture(scope="module")
def world(base_cfg):
    return build_world(base_cfg.world_spec())


def _cam_from_world(T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T = np.linalg.inv(T_world_cam)
    return cv2.Rodrigues(T[:3, :3])[0], T[:3, 3]


def test_same_seed_same_journey_and_pixels(base_cfg, world):
    a = generate(base_cfg, world)
    b = generate(base_cfg, build_world(base_cfg.world_spec()))
    np.testing.assert_array_equal(a.T_world_cam, b.T_world_cam)
    np.testing.assert_array_equal(a.lat_deg, b.lat_deg)
    assert a.detections == b.detections and len(a.detections) > 0
    np.testing.assert_array_equal(a.render(5).image_bgr, b.render(5).image_bgr)
    other_noise = generate(base_cfg.replace(seed=2), world)
    assert not np.array_equal(other_noise.lat_deg, a.lat_deg)
    np.testing.assert_array_equal(other_noise.signs[0].centre_enu, a.signs[0].centre_enu)
    other_world = build_world(base_cfg.replace(world_seed=5).world_spec())
    assert not np.allclose(other_world.signs[0].centre_enu, world.signs[0].centre_enu)


def test_rays_invert_the_lens_model():
    rays = camera_rays(KITTI_LIKE_CAMERA)
    rows, cols = np.meshgrid(np.arange(0, 375, 17), np.arange(0, 1242, 23), indexing="ij")
    p_cam = np.stack([rays.xn[rows, cols], rays.yn[rows, cols], np.ones(rows.shape)], -1)
    px, _ = cv2.projectPoints(p_cam.reshape(-1, 1, 3).astype(np.float64), np.zeros(3), np.zeros(3),
                              KITTI_LIKE_CAMERA.K, KITTI_LIKE_CAMERA.dist)
    expected = np.stack([cols, rows], -1).reshape(-1, 2)
    assert np.abs(px.reshape(-1, 2) - expected).max() < 1e-3


def test_every_mip_level_keeps_the_texture_where_it_is():
    """A bright square centred at texel 64.0 is sampled at its place from every mip level; a
    level read half a texel off slides surfaces by a different amount at each distance, which
    no camera model explains (generator 1 did: 0.5, 1.5, 3.5 texels at levels 1-3)."""
    img = np.zeros((128, 128, 1), np.uint8)
    img[60:68, 60:68] = 255
    atlas = _atlas([img])
    col = np.linspace(40.0, 88.0, 2001).astype(np.float32)
    row = np.full_like(col, 64.0)
    for level in range(4):
        v = _sample(atlas, np.zeros(len(col), int), col, row, np.full(len(col), level))[:, 0]
        assert abs(float((v * col).sum() / v.sum()) - 64.0) < 0.1, level
        v = _sample(atlas, np.zeros(len(col), int), row, col, np.full(len(col), level))[:, 0]
        assert abs(float((v * col).sum() / v.sum()) - 64.0) < 0.1, level


def test_rendered_plates_sit_where_the_model_projects_them(base_cfg, world):
    """Full resolution: each clearly visible plate covers its projected centre, with the colour of
    its face's centre, and its rendered extent matches the projected rim within a pixel."""
    cfg = base_cfg.replace(camera=KITTI_LIKE_CAMERA, n_frames=40)
    j = generate(cfg, world)
    cam = KITTI_LIKE_CAMERA
    plate_of = {int(k): i for i, k in enumerate(j.scene.sign_index) if k >= 0}
    checked = 0
    for f in (5, 20, 35):
        r = j.render(f)
        rvec, tvec = _cam_from_world(j.T_world_cam[f])
        for v in [v for v in j.views if v.frame_index == f]:
            sign = j.signs[v.sign_index]
            rim, _ = cv2.projectPoints(sign.outline_enu(), rvec, tvec, cam.K, cam.dist)
            rim = rim.reshape(-1, 2)
            lo, hi = rim.min(axis=0), rim.max(axis=0)
            if lo[0] < 1 or lo[1] < 1 or hi[0] > cam.width - 2 or hi[1] > cam.height - 2 \
                    or min(hi - lo) < 15:
                continue
            plate = world.signs.index(sign)
            # Skip plates partly hidden behind something: every rim point must be in sight.
            c_world = j.T_world_cam[f, :3, 3]
            rim_in = sign.centre_enu + 0.97 * (sign.outline_enu() - sign.centre_enu)
            _, hit = first_hits(j.scene, c_world, rim_in - c_world)
            if np.any(hit != plate_of[plate]):
                continue
            mask = r.surface_id == plate_of[plate]
            ys, xs = np.nonzero(mask)
            # Pointed plates (a diamond's tip) may leave the outermost pixel row unhit.
            assert abs(xs.min() - lo[0]) <= 1.5 and abs(xs.max() - hi[0]) <= 1.5
            assert abs(ys.min() - lo[1]) <= 1.5 and abs(ys.max() - hi[1]) <= 1.5
            # Pixel by pixel: the rendered plate lies within one pixel of the projected outline.
            projected = np.zeros(mask.shape, np.uint8)
            cv2.fillPoly(projected, [np.round(rim * 16).astype(np.int32)], 1, shift=4)
            kernel = np.ones((3, 3), np.uint8)
            assert not np.any(mask & ~cv2.dilate(projected, kernel).astype(bool))
            assert not np.any(cv2.erode(projected, kernel).astype(bool) & ~mask)
            c, _ = cv2.projectPoints(sign.centre_enu[None], rvec, tvec, cam.K, cam.dist)
            cx, cy = np.round(c.ravel()).astype(int)
            assert mask[cy, cx]
            face = world.sign_faces[plate]
            n = face.shape[0]
            expected = face[n // 2 - 1:n // 2 + 1, n // 2 - 1:n // 2 + 1].reshape(-1, 3).mean(0)
            if face[n // 2 - 3:n // 2 + 3, n // 2 - 3:n // 2 + 3].std(axis=(0, 1)).max() < 2:
                assert np.abs(r.image_bgr[cy, cx].astype(float) - expected).max() < 12
            checked += 1
    assert checked >= 3


def test_detections_are_the_projected_truth(base_cfg, world):
    exact = generate(base_cfg.replace(det_noise_px=0.0, camera=KITTI_LIKE_CAMERA, n_frames=30),
                     world)
    cam = KITTI_LIKE_CAMERA
    assert len(exact.detections) >= 10
    for det, view in zip(exact.detections, exact.views):
        sign = exact.signs[view.sign_index]
        assert det.frame_id == exact.frame_ids[view.frame_index]
        assert det.track_id == str(view.sign_index) and det.cls == sign.cls
        rvec, tvec = _cam_from_world(exact.T_world_cam[view.frame_index])
        rim, _ = cv2.projectPoints(sign.outline_enu(), rvec, tvec, cam.K, cam.dist)
        rim = rim.reshape(-1, 2)
        lo = np.clip(rim.min(axis=0), 0, [cam.width - 1, cam.height - 1])
        hi = np.clip(rim.max(axis=0), 0, [cam.width - 1, cam.height - 1])
        np.testing.assert_allclose([det.x1, det.y1, det.x2, det.y2], [*lo, *hi], atol=1e-6)
        centre, _ = cv2.projectPoints(view.p_cam[None], np.zeros(3), np.zeros(3), cam.K, cam.dist)
        x, y = centre.ravel()
        assert det.x1 < x < det.x2 and det.y1 < y < det.y2
        assert 3.0 <= np.linalg.norm(view.p_cam) <= 40.0
        to_camera = exact.T_world_cam[view.frame_index, :3, 3] - sign.centre_enu
        assert sign.normal_enu @ to_camera > 0  # its face, not its back
    noisy = generate(base_cfg.replace(camera=KITTI_LIKE_CAMERA, n_frames=30), world)
    truth = {(d.frame_id, d.track_id): d for d in exact.detections
             if 0 < d.x1 and d.x2 < cam.width - 1 and 0 < d.y1 and d.y2 < cam.height - 1}
    err = np.array([[a.x1 - b.x1, a.y1 - b.y1, a.x2 - b.x2, a.y2 - b.y2]
                    for a in noisy.detections if (b := truth.get((a.frame_id, a.track_id)))])
    assert len(err) >= 10 and abs(err.mean()) < 0.3
    assert 0.5 < err.std() < 0.9  # det_noise_px = 0.7


def test_straight_road_gives_a_straight_track():
    j = generate(SynthConfig(world_seed=2, n_frames=60, turns=0, camera=SMALL_CAMERA))
    xy = j.T_world_cam[:, :2, 3]
    centred = xy - xy.mean(axis=0)
    _, sv, _ = np.linalg.svd(centred, full_matrices=False)
    assert sv[1] / np.sqrt(len(xy)) < 1e-9
    assert np.allclose(np.linalg.norm(np.diff(xy, axis=0), axis=1), 0.8, atol=1e-3)
    fwd = j.T_world_cam[:, :3, 2]
    heading = np.degrees(np.arctan2(fwd[:, 1], fwd[:, 0]))
    assert np.ptp(heading) < 1e-6 and np.abs(fwd[:, 2]).max() < 0.03


def test_one_turn_turns_ninety_degrees_smoothly(base_cfg, world):
    j = generate(base_cfg.replace(n_frames=110), world)
    fwd = j.T_world_cam[:, :3, 2]
    heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    assert 75 < abs(np.degrees(heading[-1] - heading[0])) < 105
    assert np.degrees(np.abs(np.diff(heading))).max() < 5.0
    # The camera's y axis points down (OpenCV), up to the small pitch/roll jitter.
    assert np.all(j.T_world_cam[:, 2, 1] < -0.99)


def test_loop_comes_back_and_lane_offset_shifts_the_track():
    loop = generate(SynthConfig(world_seed=1, n_frames=241, loop=True, camera=SMALL_CAMERA))
    assert np.linalg.norm(loop.T_world_cam[-1, :3, 3] - loop.T_world_cam[0, :3, 3]) < 1.0
    shifted = generate(SynthConfig(world_seed=1, n_frames=241, loop=True, camera=SMALL_CAMERA,
                                   lateral_offset_m=2.0), loop.world)
    gap = np.linalg.norm(shifted.T_world_cam[:, :3, 3] - loop.T_world_cam[:, :3, 3], axis=1)
    np.testing.assert_allclose(gap, 2.0, atol=1e-6)


def test_gps_noise_has_the_configured_spread():
    rng = np.random.default_rng(0)
    truth = np.zeros((20000, 3))
    fixes = noisy_gps(rng, truth, 10.0, white_sigma_m=0.3, bias_sigma_m=0.3, bias_m=(1.0, 0, 0),
                      alt_sigma_m=0.5)
    horiz = fixes[:, :2] - [1.0, 0.0]
    assert abs(horiz.mean(axis=0)).max() < 0.1
    np.testing.assert_allclose(horiz.std(axis=0), np.hypot(0.3, 0.3), rtol=0.15)
    np.testing.assert_allclose(fixes[:, 2].std(), 0.5, rtol=0.05)


@pytest.mark.parametrize("rate_hz", [None, 5.0])
def test_the_fixes_are_the_antennas_where_it_is_offset(base_cfg, world, rate_hz):
    # KITTI's GPS/INS unit: 1.09 m behind, 0.25 m left of and 0.72 m below the camera.
    cfg = base_cfg.replace(n_frames=80, gps_rate_hz=rate_hz,
                           gps_antenna_offset_m=(-1.09, 0.25, -0.72))
    j = generate(cfg, world)
    plain = generate(cfg.replace(gps_antenna_offset_m=(0.0, 0.0, 0.0)), world)
    if rate_hz is None:  # a fix per frame: where the camera was, at the frame's arc length
        s_m, camera = j.s_m, j.T_world_cam[:, :3, 3]
        np.testing.assert_array_equal(plain.gps_true_enu, camera)
    else:
        s_m = cfg.speed_profile().s_at(j.gps_timestamps_s)
        camera = plain.gps_true_enu  # the camera's path at the fixes' times
    _, heading = world.road.at(s_m)
    d = j.gps_true_enu - camera
    forward = d[:, 0] * np.cos(heading) + d[:, 1] * np.sin(heading)
    left = -d[:, 0] * np.sin(heading) + d[:, 1] * np.cos(heading)
    np.testing.assert_allclose(np.column_stack([forward, left, d[:, 2]]),
                               np.tile([-1.09, 0.25, -0.72], (len(d), 1)), atol=1e-9)
    assert np.ptp(heading) > np.radians(80)  # through the turn
    # The same noise on top: the fixes moved by exactly the offset.
    np.testing.assert_allclose(j.gps_enu - plain.gps_enu, d, atol=1e-9)
    assert synth_manifest(j)["gps_antenna_offset_m"] == {"forward": -1.09, "left": 0.25,
                                                         "up": -0.72}
    assert "gps_antenna_offset_m" not in synth_manifest(plain)
    undeclared = generate(cfg.replace(gps_antenna_offset_declared=False), world)
    assert "gps_antenna_offset_m" not in synth_manifest(undeclared)
    np.testing.assert_array_equal(undeclared.gps_enu, j.gps_enu)


def test_removed_sign_is_neither_drawn_nor_detected(base_cfg, world):
    gone = world.signs[1].sign_id
    j = generate(base_cfg.replace(removed_signs=(gone,)), world)
    assert gone not in {s.sign_id for s in j.signs} and len(j.signs) == len(world.signs) - 1
    assert not np.any(j.scene.sign_index == 1)
    assert not any(j.signs[v.sign_index].sign_id == gone for v in j.views)
    with pytest.raises(ValueError):
        build_scene(world, ("no-such-sign",))


def _read_csv(z: zipfile.ZipFile, name: str) -> list[dict]:
    return list(csv.DictReader(io.StringIO(z.read(name).decode())))


def test_bundle_holds_exactly_the_contract_files(base_cfg, world, tmp_path):
    cfg = base_cfg.replace(n_frames=4)
    bundle = write_bundle(cfg, tmp_path, world)
    with zipfile.ZipFile(bundle) as z:
        names = sorted(z.namelist())
        assert names == ["detections.csv", "frames/000000.png", "frames/000001.png",
                         "frames/000002.png", "frames/000003.png", "gps.csv", "manifest.json"]
        manifest = json.loads(z.read("manifest.json"))
        assert manifest["format"] == "signmap-journey/1"
        assert manifest["camera_id"].startswith("synth-cam-")
        gps = _read_csv(z, "gps.csv")
        assert list(gps[0]) == ["frame", "timestamp_s", "lat", "lon", "alt_m"]
        assert [r["frame"] for r in gps] == ["000000", "000001", "000002", "000003"]
        dets = _read_csv(z, "detections.csv")
        assert list(z.read("detections.csv").decode().splitlines()[0].split(",")) == \
            ["frame", "track_id", "class", "x1", "y1", "x2", "y2", "score"]
        assert len(dets) > 0 and all(float(d["x1"]) < float(d["x2"]) for d in dets)
        img = cv2.imdecode(np.frombuffer(z.read("frames/000002.png"), np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (SMALL_CAMERA.height, SMALL_CAMERA.width, 3)
    truth = json.loads((tmp_path / "truth.json").read_text())
    origin = frame_at(truth["origin"]["lat"], truth["origin"]["lon"], truth["origin"]["alt_m"])
    n_obs = 0
    for sign in truth["signs"]:
        lat, lon, alt = origin.to_geodetic(np.array(sign["xyz_enu"]))
        assert abs(lat[0] - sign["lat"]) < 1e-9 and abs(alt[0] - sign["alt_m"]) < 1e-6
        for obs in sign["observations"]:
            T = np.array(truth["frames"][int(obs["frame"])]["T_world_cam"])
            p_cam = np.linalg.inv(T) @ [*sign["xyz_enu"], 1.0]
            np.testing.assert_allclose([obs["x"], obs["y"], obs["z"]], p_cam[:3], atol=1e-6)
            assert obs["z"] > 0
            n_obs += 1
    assert n_obs == len(dets)


def test_gpx_and_exif_variants(base_cfg, world, tmp_path):
    cfg = base_cfg.replace(n_frames=3, gps_format="gpx", blank_track_ids=True)
    with zipfile.ZipFile(write_bundle(cfg, tmp_path / "gpx", world)) as z:
        assert "gps.csv" not in z.namelist()
        gpx = ET.fromstring(z.read("gps.gpx"))
        pts = gpx.findall(".//{http://www.topografix.com/GPX/1/1}trkpt")
        assert len(pts) == 3
        assert pts[1].find("{http://www.topografix.com/GPX/1/1}time").text == \
            "2025-06-01T10:00:00.100Z"
        assert all(d["track_id"] == "" for d in _read_csv(z, "detections.csv"))
    j = generate(base_cfg.replace(n_frames=3), world)
    cfg = base_cfg.replace(n_frames=3, gps_format="exif")
    with zipfile.ZipFile(write_bundle(cfg, tmp_path / "exif", world)) as z:
        assert sorted(z.namelist()) == ["detections.csv", "frames/000000.jpg",
                                        "frames/000001.jpg", "frames/000002.jpg", "manifest.json"]
        gps = piexif.load(z.read("frames/000002.jpg"))["GPS"]
        d, m, s = (a / b for a, b in gps[piexif.GPSIFD.GPSLatitude])
        assert gps[piexif.GPSIFD.GPSLatitudeRef] == b"N"
        assert abs(d + m / 60 + s / 3600 - j.lat_deg[2]) < 1e-8


def test_frames_are_rich_in_sift_features(base_cfg, world):
    j = generate(base_cfg.replace(camera=KITTI_LIKE_CAMERA, n_frames=2), world)
    grey = cv2.cvtColor(render_frame(j.scene, j.rays, j.T_world_cam[1]).image_bgr,
                        cv2.COLOR_BGR2GRAY)
    assert len(cv2.SIFT_create().detect(grey, None)) > 1500

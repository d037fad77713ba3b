"""Issue 67, item 1: the GPS antenna offset a manifest declares (``gps_antenna_offset_m``) is
applied, and one nobody declares is estimated from the turn, through ``signmap process`` and
through the service.

The journey: the turn journey's first 80 frames (a 90 degree turn, 6 signs triangulated) with its
GPS fixes taken where KITTI's GPS/INS unit sits, 1.09 m behind, 0.25 m left of and 0.72 m below
the camera (``offset_journey_bundle``). Both runs reuse the camera's true calibration
(``reuse_known_calibration``), as a camera's later journeys do: what is tested is alignment.

1. ``signmap process``: declared, the signs land within 0.5 m of the truth horizontally (as on
   the same journey with its antenna at the camera) and their heights within 0.3 m; the same
   bundle without the field has its horizontal offset estimated from the turn (forward within
   0.2 m of -1.09) at ± 0.34 m, reported and, under the default 0.2 m rule, not applied: the
   signs carry the offset, ~1 m along the road; allowed 0.5 m
   (``antenna_offset_max_sigma_m``), the estimate is applied and takes most of that away.
   Heights stay ~0.8 m low either way (the vertical part cannot be estimated).
2. Over HTTP to PostgreSQL + Redis + a real Celery worker: the offset set for the vehicle by an
   admin (``PUT /api/v1/vehicles/{id}``) and the bundle without the field: the same, and the
   journey's report says the vehicle's offset was applied.
3. A bad offset is refused at upload with a 422 naming the field.
4. Two undeclared journeys of one vehicle through the service, applied under 0.3 m: the first's
   estimate alone is not sure enough, the second combines its own with the first's and is.

Measured (printed; ``-rP`` shows it), horizontal median / max sign error and median height error:
declared 0.27 / 0.35 m, heights -0.07 m; undeclared, estimated forward -1.07 ± 0.34 m, left
+0.50 ± 0.34 m: applied 0.11 / 0.12 m, heights -0.78 m; not applied 1.11 / 1.46 m, heights
-0.79 m (docs/decisions/antenna-offset.md).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.commands.usage import EXIT_OK
from app.pipeline.types import CameraModel
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import signs_enu
from tests.utils.stack import (ADMIN_KEY, auth, poll_journey, processed_by_celery, sqlite_stack,
                               upload)

APPLIED = "GPS antenna offset applied (manifest): forward -1.09 m, left +0.25 m, up -0.72 m"


def _errors(features: list[dict], truth: dict) -> tuple[dict[str, float], dict[str, float]]:
    """Per track: the horizontal distance to the true sign, and the height error (m)."""
    true = signs_enu([{"properties": {"track_id": str(s["track_id"])},
                       "geometry": {"coordinates": [s["lon"], s["lat"], s["alt_m"]]}}
                      for s in truth["signs"]], truth)
    placed = signs_enu(features, truth)
    return ({track: float(np.linalg.norm(xyz[:2] - true[track][:2]))
             for track, xyz in placed.items()},
            {track: float(xyz[2] - true[track][2]) for track, xyz in placed.items()})


def _without_offset(bundle: Path, out: Path, **changes) -> Path:
    """``bundle`` with ``gps_antenna_offset_m`` taken out of its manifest and ``changes`` set."""
    with zipfile.ZipFile(bundle) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as dst:
        for name in src.namelist():
            data = src.read(name)
            if name == "manifest.json":
                manifest = json.loads(data)
                del manifest["gps_antenna_offset_m"]
                manifest.update(changes)
                data = json.dumps(manifest).encode()
            dst.writestr(name, data)
    return out


def _process(bundle: Path, truth: dict, out_dir: Path) -> tuple[list[dict], dict]:
    """``signmap process`` with the true camera: (GeoJSON features, the report)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "cam.json").write_text(json.dumps(truth["camera"]))
    out = out_dir / "signs.geojson"
    assert main(["process", str(bundle), "--calibration", str(out_dir / "cam.json"),
                 "--out", str(out)]) == EXIT_OK
    return (json.loads(out.read_text())["features"],
            json.loads(out.with_suffix(".report.json").read_text()))


def _align_details(report: list[dict]) -> list[str]:
    return next(s for s in report if s["stage"] == "align")["details"]


def _summary(label: str, errors: dict[str, float], height: dict[str, float]) -> str:
    return (f"{label}: horizontal median {np.median(list(errors.values())):.2f} m, max "
            f"{max(errors.values()):.2f} m, median height {np.median(list(height.values())):+.2f} m "
            f"({len(errors)} signs)")


@pytest.mark.slow
def test_signmap_process_applies_the_declared_offset(offset_journey_bundle, tmp_path,
                                                     monkeypatch, capsys):
    bundle, truth = offset_journey_bundle
    monkeypatch.setenv("SIGNMAP_PIPELINE__REUSE_KNOWN_CALIBRATION", "true")
    features, report = _process(bundle, truth, tmp_path / "declared")
    errors, height = _errors(features, truth)
    undeclared = _without_offset(bundle, tmp_path / "undeclared.zip")
    capsys.readouterr()
    features_u, report_u = _process(undeclared, truth, tmp_path / "undeclared")
    assert "GPS antenna offset estimated: forward" in capsys.readouterr().out  # on the terminal
    errors_u, height_u = _errors(features_u, truth)
    # One journey's turn pins it to ± 0.34 m here: under the default 0.2 m it is only reported.
    # Allowed a wider sigma, the estimate is applied.
    monkeypatch.setenv("SIGNMAP_PIPELINE__ANTENNA_OFFSET_MAX_SIGMA_M", "0.5")
    features_e, report_e = _process(undeclared, truth, tmp_path / "estimated")
    errors_e, height_e = _errors(features_e, truth)
    print(_summary("declared", errors, height), _summary("estimated", errors_e, height_e),
          _summary("not applied (default)", errors_u, height_u), sep="\n")
    assert APPLIED in _align_details(report["report"])
    assert len(errors) >= 5 and set(errors_u) == set(errors) == set(errors_e)
    assert max(errors.values()) < 0.5 and np.median(list(errors.values())) < 0.35, errors
    assert max(abs(h) for h in height.values()) < 0.3, height
    # Undeclared, the turn tells the horizontal offset, within 0.2 m forward (KITTI's -1.09 m).
    estimated = next(d for d in _align_details(report_e["report"]) if "estimated" in d)
    forward_m = float(estimated.split("forward ")[1].split(" ")[0])
    assert abs(forward_m + 1.09) < 0.2 and estimated.endswith("applied"), estimated
    assert _align_details(report_u["report"])[-1].endswith("not applied (sigma over 0.2 m)")
    # Not applied, the signs sit where the antenna saw them: ~1 m along the road; with the estimate
    # most of that is gone. Heights are not estimated: ~0.7 m low either way.
    assert np.median(list(errors_u.values())) > np.median(list(errors.values())) + 0.5, errors_u
    assert np.median(list(errors_e.values())) < np.median(list(errors_u.values())) - 0.4
    assert np.median(list(height_e.values())) < -0.5, height_e


@pytest.mark.slow
@pytest.mark.postgres
def test_the_service_applies_the_vehicles_offset(offset_journey_bundle, own_pg_url, redis_url,
                                                 tmp_path):
    bundle, truth = offset_journey_bundle
    vehicle = json.loads(zipfile.ZipFile(bundle).read("manifest.json"))["vehicle_id"]
    offset = {"forward": -1.09, "left": 0.25, "up": -0.72}

    def set_vehicle(client) -> None:
        response = client.put(f"/api/v1/vehicles/{vehicle}", headers=auth(ADMIN_KEY),
                              json={"gps_antenna_offset_m": offset})
        assert response.status_code == 200, response.text

    undeclared = _without_offset(bundle, tmp_path / "undeclared.zip")
    body, features = processed_by_celery(undeclared.read_bytes(), truth["camera_id"],
                                         CameraModel(**truth["camera"]), own_pg_url, redis_url,
                                         tmp_path, before_upload=set_vehicle)
    assert body["status"] == "done", body["error"]
    errors, height = _errors(features, truth)
    print(f"over HTTP: median {np.median(list(errors.values())):.2f} m, max "
          f"{max(errors.values()):.2f} m, median height {np.median(list(height.values())):+.2f} m"
          f" ({len(errors)} signs)")
    assert len(errors) >= 5 and max(errors.values()) < 0.6, errors
    assert max(abs(h) for h in height.values()) < 0.3, height
    assert APPLIED.replace("(manifest)", f"(vehicle {vehicle})") in _align_details(body["report"])


@pytest.mark.slow
def test_a_vehicles_journeys_combine_their_estimates(offset_journey_bundle, tmp_path):
    """Two undeclared journeys of one vehicle through the service (SQLite, the embedded worker):
    the second adds its own estimate to the first's, and the vehicle's page shows both."""
    from app.pipeline.config import PipelineConfig
    from tests.e2e.test_fusion_rendered import seed_calibration

    bundle, truth = offset_journey_bundle
    vehicle = json.loads(zipfile.ZipFile(bundle).read("manifest.json"))["vehicle_id"]
    stack = sqlite_stack(tmp_path / "data", embedded_worker=True,
                         pipeline=PipelineConfig(reuse_known_calibration=True,
                                                 antenna_offset_max_sigma_m=0.3))
    seed_calibration(stack.url, truth["camera_id"], CameraModel(**truth["camera"]))
    fleet = stack.key("fleet")
    lines = []
    with stack.client() as client:
        for k in range(2):  # another capture time: another upload of the same drive
            data = _without_offset(bundle, tmp_path / f"{k}.zip",
                                   captured_at=f"2026-05-0{k + 1}T10:00:00Z").read_bytes()
            journey_id = upload(client, fleet, data)
            body = poll_journey(client, auth(fleet), journey_id,
                                lambda b: b["status"] in ("done", "failed"), timeout_s=300)
            assert body["status"] == "done", body["error"]
            lines.append(next(d for d in _align_details(body["report"]) if "estimated" in d))
        estimated = client.get(f"/api/v1/vehicles/{vehicle}",
                               headers=auth(ADMIN_KEY)).json()["gps_antenna_offset_estimated"]
    print(*lines, sep="\n")
    # ± 0.34 m alone is not sure enough for 0.3 m; with the first journey's it is.
    assert "earlier" not in lines[0] and lines[0].endswith("not applied (sigma over 0.3 m)")
    assert f"applied with vehicle {vehicle}'s 1 earlier journey(s)" in lines[1], lines[1]
    together = lines[1].split("together forward ")[1]
    own_sigma = float(lines[1].split("± ")[1].split(" ")[0])
    assert float(together.split("± ")[1].split(" ")[0]) < own_sigma  # two journeys know more
    assert estimated["n_journeys"] == 2 and abs(estimated["forward_m"] + 1.09) < 0.2


@pytest.mark.parametrize("offset, detail", [
    ({"forward": 109, "left": 25, "up": -72},  # centimetres
     "gps_antenna_offset_m.forward: Input should be less than or equal to 10"),
    ({"forward": -1.09, "left": 0.25}, "gps_antenna_offset_m.up: Field required"),
])
def test_a_bad_offset_is_a_422_naming_the_field(tmp_path, offset, detail):
    stack = sqlite_stack(tmp_path / "data")
    fleet = stack.key("fleet")
    files = bf.valid_files()
    files["manifest.json"] = bf.manifest_bytes(gps_antenna_offset_m=offset)
    with stack.client() as client:
        response = client.post("/api/v1/journeys", headers=auth(fleet),
                               files={"bundle": ("journey.zip", bf.zip_bytes(files),
                                                 "application/zip")})
    assert response.status_code == 422, response.text
    assert response.json()["detail"].startswith(f"manifest.json is invalid: {detail}")
    assert stack.count_journeys(fleet) == 0

"""`signmap cameras set`, `show` and `list` on the configured (SQLite) database, as `signmap keys`
works: a file refused naming its fields, a registration that wakes the camera's waiting journey
for the service's worker, and what `show` prints."""

from __future__ import annotations

import json
import subprocess

from tests.service.cameras.conftest import BODY, journey, new_camera, waiting
from tests.utils.stack import cli_on


def _cameras(stack, *words: str) -> subprocess.CompletedProcess:
    """`signmap cameras WORDS` through the command line's ``main``, in the stack's environment."""
    return cli_on(stack, "cameras", *words)


def test_cameras_set_show_and_list(sqlite, tmp_path):
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        journey_id = waiting(sqlite, client, fleet, camera_id)

    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**BODY, "cx": 99.0, "k3": 1}))
    done = _cameras(sqlite, "set", camera_id, str(bad))
    assert done.returncode == 3
    assert "  cx: the principal point must be inside the image" in done.stderr
    assert "  k3: Extra inputs are not permitted" in done.stderr
    for text in ("{oops", "[1, 2]"):
        bad.write_text(text)
        assert _cameras(sqlite, "set", camera_id, str(bad)).returncode == 3
    assert _cameras(sqlite, "set", camera_id, str(tmp_path / "missing.json")).returncode == 3
    assert "no camera" in _cameras(sqlite, "show", "no-such-camera").stderr

    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({**BODY, "sigma": {"fx": 0.5}}))
    done = _cameras(sqlite, "set", camera_id, str(cam))
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"camera {camera_id}: calibration registered as epoch 1: "
                                  f"fx 55, fy 55.5, cx 31.5, cy 23.5, k1 -0.1, k2 0.01 (64x48)")
    assert "1 journey waiting for it is queued again" in done.stdout and journey_id in done.stdout
    row = journey(sqlite, journey_id)
    assert (row.status, row.stage) == ("queued", "requeued")  # the embedded worker's sweep runs it
    again = _cameras(sqlite, "set", camera_id, str(cam))
    assert again.returncode == 0 and "registered already (epoch 1); nothing changed" in again.stdout

    shown = _cameras(sqlite, "show", camera_id)
    assert shown.returncode == 0, shown.stderr
    record = json.loads(shown.stdout)
    assert (record["camera_id"], record["source"], record["epoch"], record["waiting"]) == (
        camera_id, "registered", 1, 0)
    assert record["calibration"] == {k: BODY[k] for k in ("fx", "fy", "cx", "cy", "k1", "k2")}
    assert record["sigma"]["fx"] == 0.5 and record["epochs"][0]["registered_by"].startswith(
        "signmap cameras set (")

    listed = _cameras(sqlite, "list").stdout.splitlines()
    assert listed[0].split() == ["CAMERA", "CALIBRATION", "EPOCH", "FX", "JOURNEYS", "LEFT",
                                 "OUT", "WAITING"]
    assert [line.split() for line in listed[1:]] == [[camera_id, "registered", "1", "55.0", "0",
                                                      "0", "0"]]

"""What `signmap` prints to someone trying it: `--help` without loading the pipeline or the service
stack, COLMAP's own log only with `--verbose`, and messages in the command line's terms (the
`--calibration` file) rather than the service's (a stored calibration, uploading another
journey)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile

import pytest

from app.cli import main
from app.commands.usage import EXIT_PIPELINE_FAILED
from app.pipeline.config import PipelineConfig
from app.pipeline.steps.calibrate import no_turn_error
from tests.utils.paths import REPO

# What `signmap --help` must not wait for: each takes from a tenth of a second to seconds.
HEAVY = ("pycolmap", "cv2", "scipy", "numpy", "sqlalchemy", "alembic", "fastapi", "celery",
         "uvicorn", "app.pipeline", "app.service", "app.synth")
# glog's line prefix: severity letter, then the date (I20261201 22:37:52.279206 ...).
GLOG_LINE = re.compile(r"^[IWEF]20\d{6} ", re.MULTILINE)


@pytest.mark.parametrize("words", [(), ("process",), ("synth",)],
                         ids=lambda w: " ".join(("signmap", *w)))
def test_help_loads_no_heavy_module(words):
    code = ("import sys\nimport app.cli\ntry:\n    app.cli.main(sys.argv[1:])\n"
            "except SystemExit:\n    pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code, *words, "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.stdout.startswith("usage: signmap"), done.stderr
    assert done.stderr.strip().splitlines()[-1] == "[]"


def _without_detections(bundle, out):
    """``bundle`` with an empty detections table: the pipeline stops after calibrating."""
    with zipfile.ZipFile(bundle) as src, zipfile.ZipFile(out, "w") as dst:
        for name in src.namelist():
            data = src.read(name)
            dst.writestr(name, data.split(b"\n", 1)[0] + b"\n" if name == "detections.csv"
                         else data)
    return out


def test_a_journey_without_a_turn_is_told_to_pass_calibration(straight_journey_bundle, tmp_path,
                                                              capsys):
    bundle, _ = straight_journey_bundle
    code = main(["process", str(bundle), "--out", str(tmp_path / "signs.geojson")])
    err = capsys.readouterr().err
    assert code == EXIT_PIPELINE_FAILED
    message = err.strip().splitlines()[-1]
    assert message.startswith("signmap process: the journey could not be processed at stage "
                              "calibrate: the journey has no turn")
    assert ("pass its calibration with --calibration CAMERA.json, a JSON object with fx, fy, cx, "
            "cy" in message)
    assert "Upload a journey" not in err and "camera_id" not in err
    # The service's users are still told to upload a journey with a turn.
    assert "Upload a journey with a turn first" in no_turn_error(PipelineConfig()).reason


def test_a_given_calibration_is_named_as_given(straight_journey_bundle, tmp_path, capsys):
    bundle, truth = straight_journey_bundle
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({k: truth["camera"][k] for k in ("fx", "fy", "cx", "cy", "k1",
                                                               "k2")}))
    out = tmp_path / "signs.geojson"
    assert main(["process", str(_without_detections(bundle, tmp_path / "journey.zip")),
                 "--calibration", str(cam), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert re.search(rf"^calibrate +calibration given in {re.escape(str(cam))} used: ", printed,
                     re.MULTILINE), printed
    assert f"calibration (given in {cam}): fx={truth['camera']['fx']:.1f}" in printed
    assert "stored" not in printed
    written = json.loads(out.with_suffix(".report.json").read_text())["report"]
    calibrate = next(r for r in written if r["stage"] == "calibrate")
    assert calibrate["summary"].startswith(f"calibration given in {cam} used")


def test_verbose_shows_colmaps_log(turn_journey_bundle, tmp_path):
    # Without --verbose COLMAP keeps quiet: tests/pipeline/test_run.py looks at a whole run's
    # file descriptor 2. With it, COLMAP speaks from its first step; stop there.
    bundle, _ = turn_journey_bundle
    command = [sys.executable, "-m", "app.cli", "process", str(bundle),
               "--out", str(tmp_path / "signs.geojson"), "--verbose"]
    verbose = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
    try:
        seen = next((line for line in verbose.stderr if GLOG_LINE.match(line)), None)
    finally:
        verbose.kill()
        verbose.wait(timeout=60)
    assert seen is not None

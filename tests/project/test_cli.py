"""The ``signmap`` command line as a user meets it: help written for users, a command without its
subcommand prints that command's help, and ``signmap process`` exits 3 on bad input (a missing
file, a broken bundle or calibration) and 4 when the pipeline fails, 2 staying argparse's usage
error (issue 13, "first hour of a new user"). Fast: the pipeline itself is replaced where it
would run."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

import app.pipeline.run as pipeline_run
from app.cli import build_parser, main
from app.pipeline.types import (Calibration, CameraModel, JourneyResult, PipelineError,
                                RejectedSign, Sign, SignObservation)
from app.commands.usage import EXIT_BAD_INPUT, EXIT_PIPELINE_FAILED, EXIT_USAGE
from tests.utils.bundle_factory import broken_bundle, valid_files, zip_bytes
from tests.utils.paths import REPO


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


def _subparsers(parser):
    """(command words, parser) of every parser under ``parser``, itself included."""
    yield (), parser
    for action in parser._actions:
        if action.choices and hasattr(action, "_name_parser_map"):
            for name, child in action._name_parser_map.items():
                for words, p in _subparsers(child):
                    yield (name, *words), p


# The benchmark commands' help lives in bench/cli.py, outside this change.
USER_COMMANDS = [words for words, _ in _subparsers(build_parser())]


@pytest.mark.parametrize("words", USER_COMMANDS, ids=lambda w: " ".join(w) or "signmap")
def test_help_is_written_for_users(capsys, words):
    text = _help(capsys, *words)
    assert not re.search(r"\bapp\.[a-z_.]+|\bbench\.[a-z_]+|``", text), text
    assert "(issue" not in text, text


@pytest.mark.parametrize("words", USER_COMMANDS, ids=lambda w: " ".join(w) or "signmap")
def test_every_option_has_help(words):
    parser = dict(_subparsers(build_parser()))[words]
    for action in parser._actions:
        if action.dest in ("help",) or hasattr(action, "_name_parser_map"):
            continue
        assert action.help, f"signmap {' '.join(words)}: {action.option_strings or action.dest}"


def test_help_shows_defaults(capsys):
    synth = _help(capsys, "synth")
    assert re.search(r"--seed SEED\s+seed of the journey", synth)
    assert re.search(r"--frames FRAMES\s+number of frames to render \(default: 120\)", synth)
    serve = " ".join(_help(capsys, "serve").split())
    assert "--host HOST address to listen on (default: 127.0.0.1" in serve
    assert "--port PORT TCP port to listen on (default: 8000)" in serve
    upgrade = " ".join(_help(capsys, "db", "upgrade").split())
    assert "revision schema revision to migrate to (default: head, the newest)" in upgrade
    process = " ".join(_help(capsys, "process").split())
    assert "--out OUT where to write the signs as GeoJSON (default: signs.geojson)" in process


def test_help_documents_the_exit_codes(capsys):
    for words in ((), ("process",)):
        text = _help(capsys, *words)
        codes = re.findall(r"^  (\d)  ", text.split("exit status:")[1], flags=re.M)
        assert codes == ["0", "1", "2", "3", "4"], text


@pytest.mark.parametrize("words", [(), ("keys",), ("db",)])
def test_a_command_alone_prints_its_help(capsys, words):
    assert main(list(words)) == EXIT_USAGE
    out, err = capsys.readouterr()
    assert out.startswith(f"usage: signmap{' ' if words else ''}{' '.join(words)} ")
    assert "required" not in out + err
    if words == ("keys",):
        assert "create a key and print it" in out
    if words == ("db",):
        assert "upgrade" in out


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["process"])
    assert exc.value.code == EXIT_USAGE == 2
    with pytest.raises(SystemExit) as exc:
        main(["process", "x.zip", "--no-such-option"])
    assert exc.value.code == EXIT_USAGE
    capsys.readouterr()


def test_process_missing_bundle_says_it_does_not_exist(tmp_path, capsys):
    missing = tmp_path / "missing.zip"
    assert main(["process", str(missing), "--out", str(tmp_path / "s.geojson")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.strip() == f"signmap process: bundle {missing} does not exist"
    assert not (tmp_path / "s.geojson").exists()


def test_process_directory_as_bundle(tmp_path, capsys):
    assert main(["process", str(tmp_path)]) == EXIT_BAD_INPUT
    assert "is a directory, not a file" in capsys.readouterr().err


def test_process_missing_bundle_exit_code_from_the_shell(tmp_path):
    """The installed entry point: the code reaches the shell, the message has no Errno."""
    out = subprocess.run([sys.executable, "-m", "app.cli", "process", "missing.zip"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert out.returncode == EXIT_BAD_INPUT == 3, out.stderr
    assert out.stderr.strip() == "signmap process: bundle missing.zip does not exist"


@pytest.mark.parametrize("case", ["not_a_zip", "no_manifest", "gps_bad_lat"])
def test_process_broken_bundle_is_bad_input(tmp_path, capsys, case):
    data, fragment = broken_bundle(case)
    bundle = tmp_path / "journey.zip"
    bundle.write_bytes(data)
    assert main(["process", str(bundle)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith(f"signmap process: {bundle} is not a valid journey bundle: ")
    assert fragment in err


@pytest.fixture
def bundle(tmp_path):
    path = tmp_path / "journey.zip"
    path.write_bytes(zip_bytes(valid_files()))
    return path


@pytest.mark.parametrize("content, message", [
    (None, "calibration file {path} does not exist"),
    ("{oops", "calibration file {path} is not valid JSON"),
    ("[1, 2]", "must be a JSON object with fx, fy, cx, cy"),
    ('{"fx": 50, "fy": 50, "cx": 32}', "must be a JSON object with fx, fy, cx, cy"),
    ('{"fx": "50", "fy": 50, "cx": 32, "cy": 24}', "fx must be a number, got '50'"),
])
def test_process_bad_calibration_file(tmp_path, capsys, bundle, monkeypatch, content, message):
    monkeypatch.setattr(pipeline_run, "process_journey", lambda *a, **k: pytest.fail("ran"))
    path = tmp_path / "cam.json"
    if content is not None:
        path.write_text(content)
    assert main(["process", str(bundle), "--calibration", str(path)]) == EXIT_BAD_INPUT
    assert message.format(path=path) in capsys.readouterr().err


def test_process_pipeline_failure_exits_4(tmp_path, capsys, bundle, monkeypatch):
    def fail(*args, **kwargs):
        raise PipelineError("calibrate", "no turn to calibrate on and no known camera")

    monkeypatch.setattr(pipeline_run, "process_journey", fail)
    out = tmp_path / "signs.geojson"
    assert main(["process", str(bundle), "--out", str(out)]) == EXIT_PIPELINE_FAILED == 4
    assert capsys.readouterr().err.strip() == (
        "signmap process: the journey could not be processed at stage calibrate: no turn to "
        "calibrate on and no known camera")
    assert not out.exists()


def test_process_success_writes_signs_and_report(tmp_path, capsys, bundle, monkeypatch):
    seen = {}

    def succeed(journey, config, workdir, *, known_camera, progress, verbose):
        seen["camera"] = known_camera
        camera = known_camera
        sign = Sign("7", "stop", np.zeros(3), 49.01, 8.42, 112.5, 0.3, 0.8,
                    [SignObservation("000001", (0.0, 0.0, 10.0))])
        return JourneyResult(Calibration(camera, "given"), [sign],
                             [RejectedSign("8", "yield", "seen in one frame")], {"calibrate": 0.5})

    monkeypatch.setattr(pipeline_run, "process_journey", succeed)
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"fx": 50, "fy": 51, "cx": 32, "cy": 24}))
    out = tmp_path / "out" / "signs.geojson"
    assert main(["process", str(bundle), "--out", str(out), "--calibration", str(cam)]) == 0
    assert seen["camera"] == CameraModel(64, 48, 50.0, 51.0, 32.0, 24.0)
    text = capsys.readouterr().out
    assert "sign      7 stop" in text and "rejected 8: seen in one frame" in text
    features = json.loads(out.read_text())["features"]
    assert [f["properties"]["track_id"] for f in features] == ["7"]
    report = json.loads((tmp_path / "out" / "signs.report.json").read_text())
    assert report["calibration"]["source"] == "given" and len(report["signs"]) == 1


def test_the_process_report_gives_stage_2s_own_spread_with_none_where_unknown():
    from app.commands.process_report import report

    camera = CameraModel(64, 48, 50.0, 51.0, 32.0, 24.0)
    calib = Calibration(camera, "self", intrinsics_std=(0.5, 0.6, 0.8, float("nan"), 1e-3, 2e-3))
    out = report(JourneyResult(calib, [], [], {}))
    assert out["calibration"]["stage2_std"] == {"fx": 0.5, "fy": 0.6, "cx": 0.8, "cy": None,
                                                "k1": 1e-3, "k2": 2e-3}
    given = report(JourneyResult(Calibration(camera, "given"), [], [], {}))
    assert given["calibration"]["stage2_std"] == {}

"""``signmap process BUNDLE.zip``: the whole pipeline locally, no server or database needed, with
distinct exit codes for bad input and for a journey the pipeline could not process.

The summary it prints and the report it writes are ``app.commands.process_report``'s."""

from __future__ import annotations

import json
import logging
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from app.commands.usage import (EXIT_BAD_INPUT, EXIT_CODES_HELP, EXIT_OK, EXIT_PIPELINE_FAILED,
                                HelpFormatter)

DESCRIPTION = ("Runs the whole pipeline on one journey bundle: calibrates the camera on the "
               "journey's turns, reconstructs its motion around each sign, aligns it to GPS and "
               "triangulates the signs. Progress goes to stderr; the signs and a report are "
               "written as files.")


# What a --calibration file holds, for the help and the messages that ask for one.
CALIBRATION_FILE = ("a JSON object with fx, fy, cx, cy (the camera's focal lengths and principal "
                    "point, pixels) and optionally k1, k2 (its radial distortion), e.g. "
                    "{\"fx\": 1000, \"fy\": 1000, \"cx\": 960, \"cy\": 540, \"k1\": -0.1, "
                    "\"k2\": 0.01}")

COMMANDS = {"process": "find the signs of one journey on this machine (no server needed)",
            "pack": "make an upload bundle of a dash cam video and its GPS log"}

PACK_DESCRIPTION = ("Makes the upload bundle (docs/journey-format.md, section 1a) of a dash cam "
                    "recording: the video, its GPS log (NMEA, GPX or gps.csv; none when the "
                    "video carries GoPro GPMF or CAMM) and optional sign detections. The bundle is "
                    "checked as the service checks an upload.")


def _video_options(p) -> None:
    p.add_argument("--gps", default=None, metavar="LOG",
                   help="the GPS log of a video: .nmea (or .nma/.log/.txt: NMEA RMC+GGA), .gpx, "
                   "or .csv (timestamp_s from the video's first frame); not needed when the video "
                   "carries its own GPS (GoPro GPMF, CAMM)")
    p.add_argument("--detections", default=None, metavar="CSV",
                   help="sign detections of a video, detections.csv with `frame` the decoded "
                   "frame's 0-based index as six digits")
    p.add_argument("--camera-id", default="dashcam",
                   help="the physical camera (journeys of one camera share its calibration; "
                   "default: %(default)s)")
    p.add_argument("--gps-time-offset", type=float, default=None, metavar="SECONDS",
                   help="seconds to add to the video's clock to get GPS time, when known "
                   "(default: estimated from the journey)")


def add_parsers(sub) -> None:
    """``signmap process``."""
    p = sub.add_parser("process", description=DESCRIPTION, epilog=EXIT_CODES_HELP,
                       help=COMMANDS["process"], formatter_class=HelpFormatter)
    p.add_argument("bundle", help="the journey: a .zip of frames or a video, GPS and sign "
                   "detections as described in docs/journey-format.md, or a dash cam video "
                   "(.mp4, .mov, .mkv) with --gps")
    p.add_argument("--out", default="signs.geojson",
                   help="where to write the signs as GeoJSON (default: %(default)s)")
    p.add_argument("--report", default=None,
                   help="where to write the JSON report: calibration, timings, what each stage "
                   "tried (and why it failed), uncertainty per sign, rejected tracks and why "
                   "(default: OUT with the suffix .report.json, e.g. signs.report.json)")
    p.add_argument("--calibration", default=None, metavar="CAMERA.json",
                   help="this camera's calibration, a JSON object {fx, fy, cx, cy, k1, k2}; "
                   "checked on the journey's turn and used when the turn confirms it (else the "
                   "journey calibrates itself), and used unchecked when it has no turn")
    p.add_argument("--workdir", default=None,
                   help="keep the intermediate files (extracted frames, reconstructions) in this "
                   "directory (default: a temporary one, deleted at the end)")
    p.add_argument("--verbose", action="store_true", help="also show COLMAP's own log")
    _video_options(p)
    p.set_defaults(func=run_process)

    p = sub.add_parser("pack", description=PACK_DESCRIPTION, epilog=EXIT_CODES_HELP,
                       help=COMMANDS["pack"], formatter_class=HelpFormatter)
    p.add_argument("video", help="the recording: .mp4, .mov or .mkv")
    p.add_argument("--out", default="journey.zip", help="the bundle to write (default: %(default)s)")
    p.add_argument("--vehicle-id", default=None, help="the vehicle, when known")
    _video_options(p)
    p.set_defaults(func=run_pack)


class BadInput(Exception):
    """A file given on the command line is missing, unreadable or not what it should be."""


def _input_file(path: str, what: str) -> Path:
    """``path`` as a Path when it names a readable file; else BadInput saying what is wrong."""
    p = Path(path)
    if not p.exists():
        raise BadInput(f"{what} {path} does not exist")
    if p.is_dir():
        raise BadInput(f"{what} {path} is a directory, not a file")
    try:
        with p.open("rb"):
            pass
    except OSError as exc:
        raise BadInput(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    return p


def read_calibration(path: str) -> dict[str, float]:
    """The camera parameters of a ``--calibration`` file: a JSON object with numeric fx, fy, cx, cy
    and optionally k1, k2."""
    p = _input_file(path, "calibration file")
    try:
        params = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(f"calibration file {path} is not valid JSON: {exc}") from None
    required = ("fx", "fy", "cx", "cy")
    if not isinstance(params, dict) or any(k not in params for k in required):
        raise BadInput(f"calibration file {path} must be {CALIBRATION_FILE}")
    for key in (*required, "k1", "k2"):
        value = params.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise BadInput(f"calibration file {path}: {key} must be a number, got {value!r}")
    return params


def _pack(args, out: Path) -> Path:
    """``args.video`` (or a video given as ``process``'s bundle) packed into ``out``."""
    from app.commands.pack import PackError, pack_video

    video = _input_file(getattr(args, "video", None) or args.bundle, "video")
    gps = _input_file(args.gps, "GPS log") if args.gps else None
    detections = _input_file(args.detections, "detections file") if args.detections else None
    try:
        return pack_video(video, out, gps=gps, detections=detections, camera_id=args.camera_id,
                          vehicle_id=getattr(args, "vehicle_id", None),
                          gps_time_offset_s=args.gps_time_offset)
    except PackError as exc:
        raise BadInput(str(exc)) from None


def run_pack(args) -> int:
    """Pack ``args.video`` and check the bundle as an upload is checked."""
    from app.pipeline.bundle import check_bundle
    from app.pipeline.types import BundleError
    from app.settings import Settings

    out = Path(args.out)
    try:
        _pack(args, out)
        check = check_bundle(out, Settings().bundle)
    except BadInput as exc:
        print(f"signmap pack: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BundleError as exc:
        out.unlink(missing_ok=True)
        print(f"signmap pack: the files do not make a valid journey: {exc.reason}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"wrote {out}: {check.n_frames} frames, {check.n_detections} detections"
          + "".join(f"\nwarning: {w}" for w in check.warnings))
    return EXIT_OK


def run_process(args) -> int:
    """Run the pipeline on ``args.bundle``; returns one of the exit codes above."""
    from app import logs
    from app.commands.process_report import _progress_printer, report, stage_summary
    from app.geojson import feature_collection, journey_sign_features
    from app.pipeline.bundle import read_bundle
    from app.pipeline.detect import apply_detector, bundle_has_detections
    from app.pipeline.run import known_camera_used, process_journey
    from app.pipeline.types import BundleError, CameraModel, NoTurnError, PipelineError
    from app.settings import Settings

    logs.configure(logging.INFO if args.verbose else logging.WARNING)
    from app.commands.pack import is_video

    settings = Settings()
    out = Path(args.out)
    with tempfile.TemporaryDirectory(prefix="signmap-") as tmp:
        workdir = Path(args.workdir) if args.workdir else Path(tmp)
        try:
            bundle = _input_file(args.bundle, "bundle")
            params = read_calibration(args.calibration) if args.calibration else None
            if is_video(bundle):
                bundle = _pack(args, workdir / "journey.zip")
            elif args.gps or args.detections:
                raise BadInput("--gps and --detections go with a video; a bundle holds its own")
        except BadInput as exc:
            print(f"signmap process: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        try:
            journey = read_bundle(bundle, workdir / "bundle", limits=settings.bundle)
        except BundleError as exc:
            print(f"signmap process: {bundle} is not a valid journey bundle: {exc.reason}",
                  file=sys.stderr)
            return EXIT_BAD_INPUT
        known = None
        if params is not None:
            known = CameraModel.from_params(journey.image_width, journey.image_height, params)
        try:
            printer = _progress_printer()
            journey = apply_detector(journey, settings.detector, bundle_has_detections(bundle),
                                     progress=printer)
            result = process_journey(journey, settings.pipeline, workdir / "work",
                                     known_camera=known, progress=printer,
                                     verbose=args.verbose)
        except NoTurnError as exc:
            # The failing stage's report ends in the service's advice; this command has its own.
            stage_summary(exc.report[:-1], stream=sys.stderr)
            print(f"signmap process: the journey could not be processed at stage {exc.stage}: "
                  f"{exc.finding}, and a straight road cannot calibrate the camera: pass its "
                  f"calibration with --calibration CAMERA.json, {CALIBRATION_FILE}",
                  file=sys.stderr)
            return EXIT_PIPELINE_FAILED
        except PipelineError as exc:
            stage_summary(exc.report, stream=sys.stderr)
            print(f"signmap process: the journey could not be processed at stage {exc.stage}: "
                  f"{exc.reason}", file=sys.stderr)
            return EXIT_PIPELINE_FAILED
    source = result.calibration.source
    if source == "supplied":  # the pipeline's words are the service's, for a stored calibration
        source = f"given in {args.calibration}"
        stored = known_camera_used(journey.camera_id)
        result.report = [replace(r, summary=r.summary.replace(stored, f"calibration {source} used"))
                         for r in result.report]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(feature_collection(journey_sign_features(result.signs)), indent=1))
    report_path = Path(args.report) if args.report else out.with_suffix(".report.json")
    report_path.write_text(json.dumps(report(result, journey.warnings), indent=1))
    stage_summary(result.report)
    cal = result.calibration.camera
    print(f"calibration ({source}): fx={cal.fx:.1f} fy={cal.fy:.1f} "
          f"cx={cal.cx:.1f} cy={cal.cy:.1f} k1={cal.k1:.3f} k2={cal.k2:.3f}")
    for s in result.signs:
        alt = "" if s.alt_m is None else f" alt {s.alt_m:.2f} m"
        print(f"sign {s.track_id:>6} {s.cls:<16} lat {s.lat_deg:.7f} lon {s.lon_deg:.7f}{alt} "
              f"± {s.std_m:.2f} m ({len(s.observations)} frames)")
    for r in result.rejected:
        print(f"rejected {r.track_id}: {r.reason}")
    print(f"wrote {out} and {report_path}; stages: "
          + ", ".join(f"{k} {v:.1f}s" for k, v in result.timings_s.items()))
    for stage, parts in result.stage_parts_s.items():
        print(f"  {stage}: " + ", ".join(f"{k} {v:.1f}s" for k, v in parts.items()))
    return EXIT_OK
